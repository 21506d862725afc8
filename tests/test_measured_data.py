"""Measured trajectories: loader and its checks, initial-state estimate, protocol metric, and fitting.

Hand-computed cases: a ballistic trajectory with constant spin is estimated
back exactly (the estimator's model is exact for it), a known offset and a
known rotation give known errors. The fit is checked on tosses that jaxrb
itself generates at known friction and restitution, with the tracker's noise
(0.1 mm, 0.05°: the real tosses' free-flight residuals are 0.085 mm and 0.045° RMS, median), and on the first 12 real cube tosses for the file format.
"""

import json
import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxrb as rb
from jaxrb.fit import evaluate
from jaxrb.fit import fit_data
from jaxrb.fit import least_squares
from jaxrb.fit.initial_state import quat_exp, quat_multiply, estimate_initial_states, free_samples, length_scale
from jaxrb.fit.measured import load_trajectories, make_trajectories, save_trajectories

EXAMPLE = os.path.join(os.path.dirname(__file__), "..", "examples", "cube_tosses")
CUBE_TOSSES = os.path.join(EXAMPLE, "cube_tosses.npz")
HALF_WIDTH = 0.0524
DT = 1 / 148


def cube_scene(friction=0.25, restitution=0.1, substeps=4):
    scene = rb.Scene(dim=3, gravity=(0.0, 0.0, -9.81))
    scene.add_plane(normal=(0, 0, 1), offset=0.0, friction=1.0, restitution=0.0)
    scene.add_body(rb.Box(half_extents=(HALF_WIDTH,) * 3), mass=0.37, inertia=np.eye(3) * 8.1e-4,
                   friction=friction ** 2, restitution=restitution)
    return scene


def ballistic(p0, v0, q0, angvel, count, gravity=(0, 0, -9.81), scale=1.0):
    time = np.arange(count) * DT
    pos = scale * (p0 + v0 * time[:, None] + 0.5 * np.asarray(gravity) * time[:, None] ** 2)
    quat = quat_multiply(quat_exp(angvel[None] * time[:, None]), np.broadcast_to(q0, (count, 4)))
    return {"pos": pos[:, None], "quat": quat[:, None]}


# --- the file format ---------------------------------------------------------

def test_cube_toss_file_loads_as_it_is():
    data = load_trajectories(CUBE_TOSSES, sample_dt=1 / 148, angvel_frame="body")
    raw = np.load(CUBE_TOSSES)
    assert data.num_trajectories == 400 and data.pos.shape[2:] == (1, 3)
    assert data.length.tolist() == np.diff(raw["start"]).tolist()
    first = raw["states"][raw["start"][5]]
    np.testing.assert_allclose(data.pos[5, 0, 0], first[4:7])
    # body-frame ω rotated into the world frame: R(q) ω_body
    w, x, y, z = first[:4]
    rotation = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                         [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                         [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
    np.testing.assert_allclose(data.angvel[5, 0, 0], rotation @ first[7:10], atol=1e-12)
    with pytest.raises(ValueError, match="sample_dt"):
        load_trajectories(CUBE_TOSSES)


def test_jaxrb_layout_round_trip(tmp_path):
    pieces = [ballistic(np.zeros(3), np.ones(3), np.array([1.0, 0, 0, 0]), np.array([0, 0, 2.0]), n)
              for n in (5, 9)]
    data = make_trajectories(pieces, DT, ids=[7, 3])
    save_trajectories(tmp_path / "t.npz", data)
    back = load_trajectories(tmp_path / "t.npz")
    assert back.length.tolist() == [5, 9] and back.ids.tolist() == [7, 3] and back.sample_dt == DT
    np.testing.assert_allclose(back.pos, data.pos)
    np.testing.assert_allclose(back.quat, data.quat)
    assert back.mask.sum() == 14
    np.testing.assert_allclose(back.pos[0, 5:], np.broadcast_to(back.pos[0, 4], (4, 1, 3)))  # padding


def _state_rows(tmp_path, rows, start=None):
    start = np.array([0, len(rows)]) if start is None else start
    path = tmp_path / "bad.npz"
    np.savez(path, states=rows, start=start)
    return path


@pytest.mark.parametrize("problem, match", [
    ("nan", r"trajectory 1 \(id 1\): 'pos' sample 2, body 0, column 2: not a finite"),
    ("columns", r"13 columns per body"),
    ("quat", r"trajectory 0 \(id 0\): 'quat' sample 1, body 0: not a unit quaternion"),
    ("empty", r"trajectory 1: empty"),
    ("short", r"trajectory 0 \(id 0\): has 1 samples"),
])
def test_bad_files_name_file_trajectory_and_column(tmp_path, problem, match):
    rows = np.zeros((8, 13))
    rows[:, 0] = 1.0
    start = np.array([0, 4, 8])
    if problem == "nan":
        rows[6, 6] = np.nan
    elif problem == "columns":
        rows = rows[:, :12]
    elif problem == "quat":
        rows[1, 0] = 1.1
    elif problem == "empty":
        start = np.array([0, 4, 4, 8])
    elif problem == "short":
        start = np.array([0, 1, 8])
    path = _state_rows(tmp_path, rows, start)
    with pytest.raises(ValueError, match=match) as error:
        load_trajectories(path, sample_dt=DT, angvel_frame="body")
    assert str(path) in str(error.value)


# --- initial state and metric: hand-computed cases ---------------------------

def test_free_flight_estimate_is_exact_for_ballistic_spin():
    p0, v0 = np.array([0.1, -0.2, 0.5]), np.array([1.0, 0.3, 0.8])
    q0 = np.array([0.5, 0.5, -0.5, 0.5])
    angvel = np.array([3.0, -7.0, 12.0])
    data = make_trajectories([ballistic(p0, v0, q0, angvel, 12)], DT)
    estimate = estimate_initial_states(data, np.array([12]), (0, 0, -9.81))
    np.testing.assert_allclose(estimate["pos"][0, 0], p0, atol=1e-12)
    np.testing.assert_allclose(estimate["vel"][0, 0], v0, atol=1e-10)
    np.testing.assert_allclose(estimate["angvel"][0, 0], angvel, atol=1e-9)
    np.testing.assert_allclose(estimate["quat"][0, 0], q0, atol=1e-12)
    # a tracker that sees every length 2 % short: the free-fall acceleration gives the scale back
    scaled = make_trajectories([ballistic(p0, v0, q0, angvel, 12, scale=0.98)], DT)
    assert length_scale(scaled, np.array([12]), (0, 0, -9.81)) == pytest.approx(0.98, rel=1e-9)


def test_free_samples_stop_before_the_cube_touches():
    model, params, state = cube_scene().build(dt=DT, contact="impulse")
    drop = ballistic(np.array([0, 0, 0.2]), np.zeros(3), np.array([1.0, 0, 0, 0]), np.zeros(3), 40)
    data = make_trajectories([drop], DT)
    count = int(free_samples(model, params, data, clearance=0.005)[0])
    # closed form: the bottom face (0.2 - h at t = 0) comes within 5 mm at t = sqrt(2 (0.2 - h - 0.005) / g)
    touch = np.sqrt(2 * (0.2 - HALF_WIDTH - 0.005) / 9.81) / DT
    assert count == int(np.ceil(touch))


def test_errors_of_a_known_offset_and_rotation():
    measured_pos = jnp.zeros((2, 1, 3))
    measured_quat = jnp.tile(jnp.array([1.0, 0, 0, 0]), (2, 1, 1))
    pos = measured_pos.at[1, 0, 0].set(0.0524)  # half a width off at the second sample
    angle = np.radians(30.0)
    quat = measured_quat.at[1, 0].set(jnp.array([np.cos(angle / 2), 0, np.sin(angle / 2), 0]))
    position, rotation = evaluate.sample_errors(pos, quat, measured_pos, measured_quat, jnp.array([0.1048]))
    np.testing.assert_allclose(position, [0.0, 0.5], atol=1e-12)
    np.testing.assert_allclose(np.degrees(rotation), [0.0, 30.0], atol=1e-9)


# --- the least-squares machinery: closed forms --------------------------------

def test_levenberg_marquardt_matches_the_closed_form_fit():
    """y = a·exp(b·x): LM finds the least-squares optimum; with one residual per group the
    robust covariance is the sandwich H⁻¹ (Σ g gᵀ) H⁻¹ computed by hand."""
    x = np.linspace(0.0, 1.0, 30)
    y = 2.0 * np.exp(-1.3 * x) + 0.01 * np.random.default_rng(0).normal(size=x.size)
    residuals = lambda t: t[0] * jnp.exp(t[1] * x) - y  # noqa: E731
    result = least_squares.levenberg_marquardt(residuals, np.array([1.0, 0.0]), np.arange(x.size), tol=1e-12)
    jacobian = np.stack([np.exp(result.theta[1] * x), result.theta[0] * x * np.exp(result.theta[1] * x)], 1)
    r = np.asarray(residuals(result.theta))
    np.testing.assert_allclose(jacobian.T @ r, 0.0, atol=1e-8)  # stationary
    inverse = np.linalg.inv(jacobian.T @ jacobian)
    by_hand = inverse @ (jacobian * r[:, None]).T @ (jacobian * r[:, None]) @ inverse
    np.testing.assert_allclose(result.covariance, by_hand, rtol=1e-6)


def test_gradient_reliability_and_slope_check_flag_a_rough_cost():
    # groups that agree: high signal/noise; groups that cancel: low
    agree = np.array([[1.0], [1.1], [0.9], [1.05]])
    cancel = np.array([[1.0], [-1.1], [0.9], [-0.95]])
    assert least_squares.gradient_reliability(agree)[0] > 10
    assert least_squares.gradient_reliability(cancel)[0] < 2
    # a smooth bowl plus a fast ripple: the exact gradient at 0 is the ripple's, 100x the bowl's
    cost = lambda t: float(t[0] ** 2 + 1e-3 * np.sin(1e4 * t[0]))  # noqa: E731
    theta = np.array([0.1])
    gradient = np.array([2 * 0.1 + 10 * np.cos(1e3)])
    slopes = least_squares.slope_check(cost, theta, gradient, steps=(1e-1,))
    assert abs(slopes["gradient"]) > 5 * abs(slopes[1e-1])


# --- fitting: known values recovered from synthetic tosses --------------------

@pytest.fixture(scope="module")
def synthetic_tosses():
    """12 tosses simulated by jaxrb at μ = 0.3, e = 0.2, with the tracker's noise (module docstring)."""
    model, params, state = cube_scene(0.3, 0.2).build(dt=DT / 4, contact="impulse")
    rng = np.random.default_rng(1)
    starts = []
    for _ in range(12):
        axis = rng.normal(size=3)
        angle = rng.uniform(0, np.pi)
        quat = np.concatenate([[np.cos(angle / 2)], np.sin(angle / 2) * axis / np.linalg.norm(axis)])
        starts.append(state.replace(pos=jnp.array([[0.0, 0.0, rng.uniform(0.12, 0.16)]]),
                                    vel=jnp.array([[rng.uniform(0.5, 1.5), rng.uniform(-0.3, 0.3), -0.5]]),
                                    quat=jnp.array([quat]), angvel=jnp.array([rng.normal(0, 8, 3)])))
    import jax
    initial = jax.tree_util.tree_map(lambda *a: jnp.stack(a), *starts)
    states = evaluate.simulate(rb.make_step(model), params, initial, 60, every=4)
    noise_angle = rng.normal(0, np.radians(0.05), states.quat.shape[:-1] + (3,))
    pieces = [{"pos": np.asarray(states.pos[k]) + rng.normal(0, 1e-4, states.pos.shape[1:]),
               "quat": quat_multiply(quat_exp(noise_angle[k]), np.asarray(states.quat[k]))} for k in range(12)]
    return make_trajectories(pieces, DT, source="synthetic")


def test_fit_recovers_known_friction_and_restitution(synthetic_tosses):
    # restitution starts at 0, where the sigmoid transform cannot start: fitted on [0, 1]
    model, params, state = cube_scene(0.45, 0.0).build(dt=DT / 4, contact="impulse")
    fit = fit_data.fit_measured(model, params, state, synthetic_tosses, ("friction", "restitution"),
                                horizons=(4,), stride=2, starts=1, max_iterations=15, refine_rounds=0, scale=1.0)
    mu = float(jnp.sqrt(fit.params.friction[0]))
    e = float(fit.params.restitution[0])
    assert mu == pytest.approx(0.3, abs=0.03) and e == pytest.approx(0.2, abs=0.05)
    # the reported uncertainty (LM's, with no rollout search) is honest: the truth within 4 standard errors
    assert abs(fit.params.friction[0] - 0.09) < 4 * fit.standard_errors["friction"][0] + 1e-3
    assert abs(e - 0.2) < 4 * fit.standard_errors["restitution"][0] + 1e-3
    # the noise floor measures the noise put in: 0.1 mm per axis, 0.05° per axis (0.087° in all)
    replay = evaluate.prepare_replay(model, fit.params, state, synthetic_tosses, scale=1.0)
    floor, position_noise, rotation_noise = evaluate.noise_floor(replay, fit.params, draws=1)
    assert position_noise == pytest.approx(1e-4, rel=0.3)
    assert np.degrees(rotation_noise) == pytest.approx(0.05 * np.sqrt(3), rel=0.3)
    assert np.all(np.isfinite(floor.position)) and np.all(floor.position > 0)


def test_command_line_fit_and_evaluate(synthetic_tosses, tmp_path, capsys):
    from jaxrb.cli.main import main
    data = tmp_path / "tosses.npz"
    save_trajectories(data, synthetic_tosses)
    scene = os.path.join(EXAMPLE, "cube.json")
    out = tmp_path / "fitted.json"
    assert main(["fit", scene, str(data), "--out", str(out), "--trajectories", "0:4", "--fields", "friction",
                 "--budget", "60"]) == 0
    printed = capsys.readouterr().out
    assert "friction" in printed and "position:" in printed and out.exists()
    rb.load_scene(out).build()  # the fitted file is a scene file
    assert main(["evaluate", str(out), str(data), "--trajectories", "0:4", "--plot", str(tmp_path / "e.png")]) == 0
    printed = capsys.readouterr().out
    assert "over 4 trajectories" in printed and (tmp_path / "e.png").exists()
    assert main(["evaluate", scene, CUBE_TOSSES]) == 2  # the state-row layout needs --sample-dt
    assert "sample_dt" in capsys.readouterr().err


def test_fitted_scene_file_loads_and_keeps_the_fit(synthetic_tosses, tmp_path):
    source = rb.scenefile.SceneFile(cube_scene(), {"dt": DT, "substeps": 4, "contact": "impulse"})
    _, params, _ = source.build()
    fitted = params.replace(friction=jnp.array([0.123]), contact_hertz=jnp.array(77.0))
    data = fit_data.fitted_scene(source, fitted, ("friction", "contact_hertz"))
    path = tmp_path / "fitted.json"
    path.write_text(json.dumps(data))
    _, back, _ = rb.load_scene(path).build()
    assert float(back.friction[0]) == pytest.approx(0.123) and float(back.contact_hertz) == pytest.approx(77.0)
    with pytest.raises(ValueError, match="'dt'"):
        fit_data.check_fields(("dt",))
    # a fitted shape scale is written as the scaled shape, mass properties unchanged
    scaled = params.replace(shape_scale=jnp.array([0.98]))
    path.write_text(json.dumps(fit_data.fitted_scene(source, scaled, ("shape_scale",))))
    model, back, _ = rb.load_scene(path).build()
    assert model.shapes[0].half_extents == pytest.approx((0.98 * HALF_WIDTH,) * 3)
    np.testing.assert_allclose(back.inertia, params.inertia, rtol=1e-12)
    np.testing.assert_allclose(back.shape_scale, 1.0)


@pytest.mark.parametrize("contact", ["impulse", "penalty"])
def test_shape_scale_moves_the_resting_height_and_its_gradient_is_the_half_width(contact):
    """A cube resting on a plane: its centre at s·h, so d z / d s = h (closed form), through the
    general step (impulse) and through rollout's component form of penalty contact."""
    scene = rb.Scene(dim=3)
    scene.add_plane(normal=(0, 0, 1))
    scene.add_body(rb.Box(half_extents=(0.1, 0.1, 0.1)), mass=1.0, pos=(0, 0, 0.3))
    model, params, state = scene.build(dt=1 / 240, substeps=4, contact=contact)
    step = rb.make_step(model)

    def rest_height(scale):
        return rb.rollout(step, state, params.replace(shape_scale=jnp.array([scale])), 480).pos[-1, 0, 2]

    # resting sink: the impulse soft step's and the default penalty spring's, under 0.1 mm
    assert float(rest_height(1.5)) == pytest.approx(0.15, abs=1e-4)
    assert float(jax.grad(rest_height)(1.5)) == pytest.approx(0.1, rel=1e-3)


def test_shape_scale_gradient_of_the_penalty_adjoint_equals_autodiffs():
    """rollout(..., adjoint=True) differentiates a sphere's and a capsule's radius through the
    shape scale like autodiff of the same rollout (the adjoint's radius cotangent)."""
    for shape in (rb.Sphere(0.1), rb.Capsule(0.05, 0.1)):
        scene = rb.Scene(dim=3)
        scene.add_plane(normal=(0, 0, 1))
        scene.add_body(shape, mass=1.0, pos=(0, 0, 0.12), vel=(0.3, 0, 0), angvel=(1.0, 2.0, 0.5))
        model, params, state = scene.build(dt=1 / 240, substeps=2, contact="penalty")
        step = rb.make_step(model)

        def loss(scale, adjoint):
            final = rb.rollout(step, state, params.replace(shape_scale=jnp.array([scale])), 120, adjoint=adjoint)
            return jnp.sum(final.pos[-1] ** 2) + jnp.sum(final.quat[-1, 0, 1:] ** 2)

        assert float(jax.grad(loss)(1.2, True)) == pytest.approx(float(jax.grad(loss)(1.2, False)), rel=1e-9)


def test_bootstrap_errors_of_a_mean_match_the_standard_error():
    """Per-group losses ℓ_k = (θ - c_k)²: the minimiser of their mean is the mean of the c_k, whose
    standard error is std(c)/√G; a coordinate the losses do not depend on runs to the grid's edge."""
    rng = np.random.default_rng(3)
    centres = rng.normal(size=200)
    theta = np.array([centres.mean(), 0.0])

    def per_group(points):
        return (points[:, :1] - centres[None]) ** 2 + 0.0 * points[:, 1:]

    errors = least_squares.bootstrap_errors(per_group, theta, half_width=0.3, points=9, resamples=2000)
    assert errors[0] == pytest.approx(centres.std() / np.sqrt(200), rel=0.1)
    assert np.isinf(errors[1])
