"""jaxrb: differentiable rigid-body physics in pure JAX."""

# First: importing jaxrb.compile sets XLA_FLAGS, which must happen before JAX starts.
from jaxrb.compile import jit
import jax as _jax
from jaxrb.math import quaternion
from jaxrb.physics.collision.pairs import ContactSet
from jaxrb.physics.collision.pairs import detect as _detect
from jaxrb.physics.dynamics import (angular_momentum, kinetic_energy, potential_energy,
                                    total_angular_momentum, world_inertia, wrench_at_points)
from jaxrb.model.joints import Ball, Connect, Fixed, Free, Hinge, Slider, Weld
from jaxrb.model.options import Impulse, Penalty
from jaxrb.scene import Scene
from jaxrb.files.scenefile import SceneFile, load_scene, save_scene
from jaxrb.model.shapes import Box, Capsule, Circle, PointMasses, Polygon, Sphere, point_mass_properties
from jaxrb.physics.step import make_step, rollout
from jaxrb.model.types import COLLIDING, INACTIVE, RESTING, SEPARATING, Model, Params, State, Wrench

# Jitted (the Model static), because users call it outside jit: op by op, one call
# on a 6-body scene compiled for 9.9 s against 1.0 s jitted (docs/design.md,
# 'Loops compiled whole'). Inside a jitted, vmapped or differentiated function it is inlined.
# Plain jax.jit: JAX refuses compiler_options (rb.jit's) on a jit nested in another.
detect_contacts = _jax.jit(_detect, static_argnums=0)

# Modules, not functions: rb.sweep.batch_params, rb.sysid.fit, rb.render.animate, ...
from jaxrb import analytic, render, sweep  # noqa: E402  (they use the names above)
from jaxrb.files import scenefile  # noqa: E402
from jaxrb.fit import sysid  # noqa: E402
# Measured data: rb.measured.load_trajectories, rb.fit_data.fit_measured, rb.evaluate.score.
from jaxrb.fit import evaluate, fit_data, measured  # noqa: E402
from jaxrb.physics import joints  # noqa: E402  (rb.joints.qpos_qvel, rb.joints.set_qpos_qvel)

__version__ = "0.1.0"

__all__ = [
    "COLLIDING", "ContactSet", "SceneFile", "analytic", "evaluate", "fit_data", "load_scene", "measured",
    "render", "save_scene",
    "scenefile", "INACTIVE", "RESTING", "SEPARATING", "detect_contacts",
    "Ball", "Connect", "Fixed", "Free", "Hinge", "Slider", "Weld", "joints",
    "Box", "Capsule", "Circle", "Impulse", "Model", "Params", "Penalty", "PointMasses", "Polygon", "Scene", "Sphere",
    "State", "Wrench", "angular_momentum", "jit", "kinetic_energy", "make_step", "point_mass_properties",
    "potential_energy", "quaternion", "rollout", "sweep", "sysid", "total_angular_momentum",
    "world_inertia", "wrench_at_points",
]
