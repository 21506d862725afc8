"""Joint trees (``rb.joints``): MuJoCo's coordinates of a State, and the articulated step's parts.

``rb.joints.qpos_qvel(model, params, state)`` and
``rb.joints.set_qpos_qvel(model, params, state, qpos, qvel)`` read and write
MuJoCo's ``qpos``/``qvel``; :mod:`.kinematics`, :mod:`.dynamics`,
:mod:`.constraints` and :mod:`.step` hold the step of a scene with joints,
:mod:`.tree` builds its static tree.
"""

from jaxrb.physics.joints.coordinates import qpos_qvel, set_qpos_qvel

__all__ = ["qpos_qvel", "set_qpos_qvel"]
