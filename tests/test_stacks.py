"""Stacks that must stand: issue-3 criteria over 10 s.

Criteria: top-box horizontal drift < 1 cm, penetration < 5 mm, and max speed
in the last second < 1 cm/s. Impulse contact at h = 1/60 s: the stiffness of
the soft contact comes from substeps (default contact_hertz =
0.25·substeps/dt). ``Scene.build(dt=1/60)`` with no other option (8
substeps) must hold the 3D stack, the pyramid and a 1:50 ratio to the issue-60
figures (sinks < 2 mm, drifts < 1 mm); 4 substeps hold them to the looser
issue-3 criteria (see jaxrb/physics/contact/impulse.py, "Stiffness and stacks"). Penalty contact at its
test step h = 1 ms for the 3D stack and the pyramid; it does not hold the
20-box 2D column or the 100:1 ratio (see the penalty module's limits).
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxrb as rb
from jaxrb.bench.contact import column_scene, pyramid2d_scene

pytestmark = pytest.mark.slow
HALF = 0.1  # 0.2 m boxes
SECONDS = 10.0
DT = 1.0 / 60.0
SAVE_EVERY = 0.1  # s between saved states
PENALTY = dict(contact="penalty", dt=1e-3)


def run_stack(scene, **build):
    build = {"dt": DT, **build}
    model, params, state = scene.build(**build)
    step = rb.make_step(model)
    every = int(round(SAVE_EVERY / build["dt"]))
    num_steps = int(round(SECONDS / build["dt"]))
    traj = jax.jit(lambda s, p: rb.rollout(step, s, p, num_steps, every=every))(state, params)
    return model, params, state, traj


def check_standing(model, params, state, traj, top):
    """Issue-3 criteria: top drift, deepest contact penetration, last-second speed."""
    drift = float(jnp.max(jnp.linalg.norm(traj.pos[:, top, :-1] - state.pos[top, :-1], axis=-1)))
    contacts = jax.jit(jax.vmap(lambda s: rb.detect_contacts(model, params, s)))(traj)
    penetration = float(jnp.max(jnp.where(contacts.active, -contacts.dist, 0.0)))
    last_second = int(round(1.0 / SAVE_EVERY))
    speed = float(jnp.max(jnp.linalg.norm(traj.vel[-last_second:], axis=-1)))
    assert np.all(np.isfinite(np.asarray(traj.pos)))
    assert drift < 0.01, f"top drifted {drift * 100:.2f} cm"
    assert penetration < 0.005, f"penetration {penetration * 1000:.2f} mm"
    assert speed < 0.01, f"moving at {speed * 100:.2f} cm/s in the last second"
    # Still a stack: the top body is about where it started (no collapse).
    assert abs(float(traj.pos[-1, top, -1] - state.pos[top, -1])) < 0.02


def check_sink_and_drift(state, traj, top, rest_height):
    """Issue-60 figures for defaults: the top sinks < 2 mm below its rest height and drifts < 1 mm."""
    sink = rest_height - float(traj.pos[-1, top, -1])
    drift = float(jnp.max(jnp.linalg.norm(traj.pos[:, top, :-1] - state.pos[top, :-1], axis=-1)))
    assert abs(sink) < 2e-3, f"sank {sink * 1000:.2f} mm"
    assert drift < 1e-3, f"drifted {drift * 1000:.2f} mm"


@pytest.mark.parametrize("build", [dict(substeps=4), dict(substeps=8, contact=rb.Impulse(solver="jacobi")), PENALTY],
                         ids=["impulse", "impulse-jacobi", "penalty"])
def test_ten_box_stack_3d(build):
    check_standing(*run_stack(column_scene([1.0] * 10), **build), top=9)


@pytest.mark.parametrize("masses", [[1.0] * 10, [1.0, 50.0]], ids=["ten-boxes", "one-to-fifty"])
def test_defaults_at_sixty_hertz_stand(masses):
    """``build(dt=1/60)`` and nothing else: rest height with every box touching, 0.2 m boxes."""
    model, params, state, traj = run_stack(column_scene(masses))
    assert model.contact == "impulse" and model.substeps == 8
    top = len(masses) - 1
    check_standing(model, params, state, traj, top)
    check_sink_and_drift(state, traj, top, rest_height=HALF * (2 * len(masses) - 1))


def test_twenty_box_stack_2d():
    check_standing(*run_stack(column_scene([1.0] * 20, dim=2), substeps=8), top=19)


def test_mass_ratio_hundred_to_one():
    check_standing(*run_stack(column_scene([1.0, 100.0]), substeps=8), top=1)


@pytest.mark.parametrize("build", [dict(substeps=4), dict(), PENALTY], ids=["impulse", "defaults", "penalty"])
def test_pyramid_of_ten_rows_2d(build):
    scene = pyramid2d_scene(rows=10)  # the benchmark's scene: 0.2 m boxes, 5 % gaps, μ = 0.5
    assert scene.num_bodies == 55
    model, params, state, traj = run_stack(scene, **build)
    check_standing(model, params, state, traj, top=54)  # bodies are added row by row
    if not build:
        check_sink_and_drift(state, traj, 54, rest_height=float(state.pos[54, -1]))


def test_standing_check_fails_on_a_stack_that_falls():
    """The criteria can fail: at 5 Hz soft contacts (a twelfth of the default) the stack sinks and topples."""
    with pytest.raises(AssertionError):
        check_standing(*run_stack(column_scene([1.0] * 10), substeps=4, contact=rb.Impulse(hertz=5.0)), top=9)
