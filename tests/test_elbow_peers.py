"""The elbow tosses' peers (benchmarks.elbow_peers): MuJoCo and Bullet start where the data does.

Skipped where MuJoCo or pybullet is missing, or the elbow data
(``JAXRB_ELBOW_TOSSES``) or jaxrb's elbow model is absent. A few tosses only:
every test runs in seconds.
"""

import functools
import os
import types

import numpy as np
import pytest

from benchmarks import elbow_peers

DT = 1 / 148  # s, the tosses' sample spacing
SCENE = os.path.join(os.path.dirname(__file__), "..", "examples", "elbow_tosses", "elbow.xml")


@pytest.fixture(scope="module")
def tosses():
    """Six tosses with estimated starts (c >= 5), the first three and the three spinning fastest there, replayed by
    the protocol; jaxrb's model given the URDF's isotropic inertia, as the peers have it."""
    import jax
    import jaxrb as rb
    from jaxrb.fit import evaluate, joint_data

    npz, urdf = elbow_peers.data_paths()
    if not (os.path.exists(npz) and os.path.exists(urdf) and os.path.exists(SCENE)):
        pytest.skip(f"no elbow data at {npz} or no model at {SCENE}")
    model, params, state = rb.load_scene(SCENE).build(dt=DT / 5, substeps=1, contact="penalty", dtype="float64")
    inertia = np.broadcast_to(elbow_peers.LINK_INERTIA * np.eye(3), (2, 3, 3))
    params = params.replace(inertia=np.asarray(inertia, np.asarray(params.inertia).dtype))
    data = joint_data.load_joint_trajectories(npz, model, params, sample_dt=DT)
    replay = evaluate.prepare_replay(model, params, state, data)
    qpos0, qvel0 = np.asarray(replay.initial.qpos), np.asarray(replay.initial.qvel)
    estimated = np.flatnonzero(np.asarray(replay.num_free) >= 5)
    spin = np.linalg.norm(qvel0[estimated, 3:6], axis=1) + np.abs(qvel0[estimated, 6])
    pick = np.concatenate([estimated[:3], estimated[np.argsort(-spin)[:3]]])
    return types.SimpleNamespace(
        qpos0=qpos0[pick], qvel0=qvel0[pick], first_contact=np.asarray(replay.num_free)[pick],
        initial=jax.tree_util.tree_map(lambda a: a[pick], replay.initial), step=replay.step, params=params,
        trajectories=replay.trajectories.subset(pick), sizes=replay.sizes, urdf=urdf)


def peers(urdf):
    """(name, simulate, default parameters) of both peers, skipping where either is missing."""
    pytest.importorskip("mujoco")
    pytest.importorskip("pybullet")
    return (("mujoco", elbow_peers.simulate_mujoco, elbow_peers.MUJOCO_DEFAULTS),
            ("bullet", functools.partial(elbow_peers.simulate_bullet, urdf_path=urdf), elbow_peers.BULLET_DEFAULTS))


def rotation_angle(a, b):
    """Angle (rad) between unit quaternions (..., 4), from the vector part (exact near zero)."""
    w = np.sum(a * b, axis=-1)
    vector = np.linalg.norm(b[..., :1] * a[..., 1:] - a[..., :1] * b[..., 1:] - np.cross(a[..., 1:], b[..., 1:]),
                            axis=-1)
    return 2.0 * np.arctan2(vector, np.abs(w))


def test_both_peers_start_at_the_measured_poses_of_both_links(tosses):
    """Sample 0 is the initial state: both links' box centres and orientations equal the measured ones,
    which jaxrb computed from the same coordinates with the URDF's kinematics (R2 = R1 Ry(θ)): this checks
    the state setting (pybullet's world-frame angular velocity does not matter here, its pose does)."""
    measured = tosses.trajectories
    for name, simulate, parameters in peers(tosses.urdf):
        pos, quat = simulate(tosses.qpos0, tosses.qvel0, 1, DT, parameters)
        np.testing.assert_allclose(pos[:, 0], measured.pos[:, 0], rtol=0, atol=1e-12, err_msg=name)
        assert rotation_angle(quat[:, 0], measured.quat[:, 0]).max() < 1e-12, name


def test_free_flight_agrees_with_jaxrb_and_between_peers(tosses):
    """Over the two samples after the start (before first contact, so free flight) both peers follow
    jaxrb's own simulation of the same initial states and inertia, run at the peers' step h = dt/10.
    All three are first order in h (MuJoCo and Bullet step semi-implicit Euler: each drops a body
    g h t / 2 below the parabola, 2.3e-5 m a sample, and jaxrb at the same h drops it as much); they
    differ in how the rotation is integrated, by O(h² ω³ t) ≈ 2e-5 rad at the fastest start here
    (ω ≈ 15 rad/s, t = 2 samples), times the 0.06 m lever arm in position. Tolerances 2e-5 rad and
    2e-6 m; measured 2.5e-6 rad and 1.6e-7 m. MuJoCo and Bullet, the same integrator, agree to 1e-14."""
    from jaxrb.fit import evaluate

    assert np.all(tosses.first_contact >= 3)  # samples 1 and 2 after the start s = c - 3 are free
    params = tosses.params.replace(dt=np.asarray(DT / elbow_peers.SUBSTEPS, np.asarray(tosses.params.dt).dtype))
    states = evaluate.simulate(tosses.step, params, tosses.initial, 3, elbow_peers.SUBSTEPS)
    reference_pos, reference_quat = np.asarray(states.pos), np.asarray(states.quat)
    results = {}
    for name, simulate, parameters in peers(tosses.urdf):
        pos, quat = simulate(tosses.qpos0, tosses.qvel0, 3, DT, parameters, table=False)
        results[name] = pos, quat
        np.testing.assert_allclose(pos, reference_pos, rtol=0, atol=2e-6, err_msg=name)
        assert rotation_angle(quat, reference_quat).max() < 2e-5, name
    (pos_m, quat_m), (pos_b, quat_b) = results["mujoco"], results["bullet"]
    np.testing.assert_allclose(pos_m, pos_b, rtol=0, atol=1e-10)
    assert rotation_angle(quat_m, quat_b).max() < 1e-10


def test_a_tiny_fit_returns_finite_values(tosses):
    """Grid and Nelder–Mead on 2 tosses with a handful of evaluations: finite, within budget."""
    two = tosses.trajectories.subset(slice(0, 2))
    qpos0, qvel0 = tosses.qpos0[:2], tosses.qvel0[:2]
    grids = {"mujoco": {"friction": (0.2, 0.5), "timeconst": (0.01,), "dampratio": (1.0,)},
             "bullet": {"friction": (0.2, 0.5), "stiffness": (3000.0,), "damping": (30.0,)}}
    for name, simulate, _ in peers(tosses.urdf):
        lines = []
        best, error, evaluations, seconds = elbow_peers.fit_peer(simulate, qpos0, qvel0, two, tosses.sizes,
                                                                 grids[name], log=lines.append, max_evaluations=3)
        assert set(best) == set(grids[name]) and all(np.isfinite(v) and v > 0 for v in best.values()), name
        fixed = "timeconst" if name == "mujoco" else "stiffness"
        assert best[fixed] == grids[name][fixed][0]  # a one-value grid holds it fixed
        assert np.isfinite(error) and 0 < error < elbow_peers.FAILED_ERROR, name
        assert evaluations == 2 + 3 and np.isfinite(seconds) and lines, name
        position, rotation = elbow_peers.score_peer(simulate, qpos0, qvel0, two, tosses.sizes, best)
        assert np.mean(position) == pytest.approx(error, rel=1e-6) and np.all(np.isfinite(rotation)), name
