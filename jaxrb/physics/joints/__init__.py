"""Joint trees (``rb.joints``): MuJoCo's coordinates of a State, the articulated step's parts, identification.

``rb.joints.qpos_qvel(model, params, state)`` and
``rb.joints.set_qpos_qvel(model, params, state, qpos, qvel)`` read and write
MuJoCo's ``qpos``/``qvel``; ``rb.joints.joint_wrenches`` what each joint
transmits (:mod:`.reactions`); :mod:`.kinematics`, :mod:`.dynamics`,
:mod:`.constraints` and :mod:`.step` hold the step of a scene with joints,
:mod:`.tree` builds its static tree. :mod:`.identification` holds the
inverse dynamics and the linear-in-parameters identification model
(``rb.joints.inverse_dynamics``, ``regressor``, ``standard_parameters``,
``parameter_names``, ``base_parameters``, ``fit_base_parameters``).
"""

from jaxrb.physics.joints.coordinates import qpos_qvel, set_qpos_qvel
from jaxrb.physics.joints.reactions import joint_wrenches
from jaxrb.physics.joints.identification import (BaseFit, base_parameters, fit_base_parameters, inverse_dynamics,
                                                 parameter_names, regressor, standard_parameters)

__all__ = ["qpos_qvel", "set_qpos_qvel", "joint_wrenches", "inverse_dynamics", "regressor", "standard_parameters", "parameter_names",
           "base_parameters", "fit_base_parameters", "BaseFit"]
