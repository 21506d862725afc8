"""Measured articulated bodies (jaxrb.fit.joint_data) on the real elbow tosses: layout, kinematics, protocol.

The checks compare with what the data README measured independently (the
lowest corner at rest on the table, the free-flight errors of the protocol's
initial states) and with the README's closed form for the base velocity.
"""

import os

import numpy as np
import pytest

import jaxrb as rb
from jaxrb.fit import evaluate, fit_data, joint_data
from jaxrb.fit.initial_state import quat_conjugate, quat_log, quat_multiply
from jaxrb.fit.measured import load_trajectories, rotate_vectors, save_trajectories

FOLDER = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "examples", "elbow_tosses")
DATA = os.path.join(FOLDER, "elbow_tosses.npz")
HALF = np.array([0.05, 0.025, 0.025])
CORNERS = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).reshape(3, -1).T * HALF  # (8, 3)


@pytest.fixture(scope="module")
def scene():
    return rb.load_scene(os.path.join(FOLDER, "elbow.xml")).build(dt=1 / 148 / 2, substeps=1, contact="penalty",
                                                                  penalty_stiffness=8000.0, penalty_damping=50.0)


@pytest.fixture(scope="module")
def tosses(scene):
    model, params, _ = scene
    return joint_data.load_joint_trajectories(DATA, model, params, sample_dt=1 / 148)


def lowest_corner(pos, quat):
    """(...,) height of the lowest of both boxes' 8 corners; pos (..., 2, 3), quat (..., 2, 4)."""
    corners = pos[..., None, :] + rotate_vectors(np.repeat(quat[..., None, :], 8, -2),
                                          np.broadcast_to(CORNERS, pos.shape[:-1] + (8, 3)))
    return corners[..., 2].min(axis=(-1, -2))


def test_link_poses_by_the_models_kinematics_put_every_toss_on_the_table_at_rest(tosses):
    # The README: with the URDF's kinematics the lowest corner at every toss's last sample is at z = 0.
    # Link 2's pose comes from jaxrb's forward kinematics of the MJCF; float32 params: 1e-6 m.
    rows = np.arange(tosses.num_trajectories)
    last = tosses.length - 1
    assert tosses.num_trajectories == 400 and tosses.qpos.shape[-1] == 8 and tosses.qvel.shape[-1] == 7
    assert np.abs(lowest_corner(tosses.pos[rows, last], tosses.quat[rows, last])).max() < 1e-6


def test_hinge_angles_are_unwrapped_and_velocities_are_the_recorded_ones(tosses):
    raw = np.load(DATA)
    states, start = raw["states"], raw["start"]
    steps = np.abs(np.diff(tosses.qpos[..., 7], axis=1))[tosses.mask[:, 1:]]
    assert steps.max() < 0.6  # README: no unwrapped step above 0.53 rad (the raw angle jumps by 2π)
    np.testing.assert_allclose(np.mod(tosses.qpos[0, :tosses.length[0], 7] + np.pi, 2 * np.pi) - np.pi,
                               states[start[0]:start[1], 7], atol=1e-12)
    # Link 1's frame origin is its centre of mass: its world velocity is the base's recorded one.
    np.testing.assert_allclose(tosses.vel[0, :tosses.length[0], 0], states[start[0]:start[1], 11:14], atol=1e-5)
    np.testing.assert_allclose(tosses.qvel[0, :tosses.length[0], 3:6], states[start[0]:start[1], 8:11])


def test_first_contact_is_the_lowest_corner_within_20_mm(scene, tosses):
    model, params, _ = scene
    first = joint_data.first_contacts(model, params, tosses)
    near = lowest_corner(tosses.pos, tosses.quat) < joint_data.JOINT_CLEARANCE
    assert np.array_equal(first, np.maximum(np.argmax(near, axis=1), 2))  # at least 2 samples, as for the cubes
    assert np.median(first) == 19  # README: first contact at sample 0-39, median 19


def test_initial_states_follow_the_protocol(scene, tosses):
    """Base velocity against the README's closed form (equal masses), and free flight over s+1 .. c-1."""
    model, params, state = scene
    some = tosses.subset(slice(0, 40))
    first = joint_data.first_contacts(model, params, some)
    start, qpos, qvel = joint_data.estimate_joint_starts(model, params, some, first)
    assert np.array_equal(start, np.maximum(first - 3, 0))
    k = int(np.flatnonzero(first >= 5)[0])
    poses = joint_data.body_poses(model, params, qpos[k], qvel[k])
    omega1 = rotate_vectors(qpos[k, 3:7], qvel[k, 3:6])
    omega2 = omega1 + qvel[k, 6] * rotate_vectors(qpos[k, 3:7], np.array([0.0, 1.0, 0.0]))
    hinge = rotate_vectors(qpos[k, 3:7], np.array([-0.035, 0.06, 0.0]))
    arm2 = rotate_vectors(poses["quat"][1], np.array([0.035, 0.0, 0.0]))
    com_vel = poses["vel"].mean(axis=0)
    np.testing.assert_allclose(qvel[k, :3], com_vel - 0.5 * (np.cross(omega1, hinge) + np.cross(omega2, arm2)),
                               atol=1e-5)
    # Free flight from the estimates: the README measured 0.55 % and 0.28° (MuJoCo, samples s+1 .. c-1).
    replay = evaluate.prepare_replay(model, params, state, some)
    states = evaluate.simulate(replay.step, params, replay.initial, 6, replay.every)
    position, rotation = evaluate.sample_errors(np.asarray(states.pos), np.asarray(states.quat),
                                                replay.trajectories.pos[:, :6], replay.trajectories.quat[:, :6],
                                                replay.sizes)
    before = (np.arange(6)[None] >= 1) & (np.arange(6)[None] < (first - start)[:, None])
    assert 100 * np.mean(np.asarray(position)[before]) < 1.0
    assert np.degrees(np.mean(np.asarray(rotation)[before])) < 0.5


def test_trajectories_cut_to_their_starts_and_saved_with_coordinates(tosses, tmp_path):
    some = tosses.subset(slice(0, 3))
    cut = some.from_samples([0, 5, 10])
    assert np.array_equal(cut.length, some.length - [0, 5, 10])
    np.testing.assert_array_equal(cut.qpos[1, 0], some.qpos[1, 5])
    np.testing.assert_array_equal(cut.pos[2, cut.length[2] - 1], some.pos[2, some.length[2] - 1])
    with pytest.raises(ValueError, match="rescaled"):
        some.scaled(0.98)
    save_trajectories(tmp_path / "saved.npz", some)
    again = load_trajectories(tmp_path / "saved.npz")
    np.testing.assert_allclose(again.qvel, some.qvel)
    np.testing.assert_allclose(again.quat, some.quat)


def test_bad_joint_data_is_refused_by_name(scene, tmp_path):
    model, params, _ = scene
    raw = dict(np.load(DATA))
    wrong = tmp_path / "wrong.npz"
    np.savez(wrong, states=raw["states"][:, :13], start=raw["start"])
    with pytest.raises(ValueError, match="'states' must have 15 columns"):
        joint_data.load_joint_trajectories(wrong, model, params, sample_dt=1 / 148)
    states = raw["states"].copy()
    states[raw["start"][2] + 4, 9] = np.nan
    bad = tmp_path / "nan.npz"
    np.savez(bad, states=states, start=raw["start"])
    with pytest.raises(ValueError, match="trajectory 2: 'states' sample 4, column 9"):
        joint_data.load_joint_trajectories(bad, model, params, sample_dt=1 / 148)
    free = rb.Scene(dim=3)
    free.add_body(rb.Box((0.05, 0.025, 0.025)), mass=0.37)
    free_model, free_params, _ = free.build(dt=0.01)
    with pytest.raises(ValueError, match="free joint"):
        joint_data.load_joint_trajectories(DATA, free_model, free_params, sample_dt=1 / 148)


def test_the_urdf_with_a_floating_base_has_the_datas_kinematics(scene, tosses):
    urdf = rb.load_scene(os.path.join(FOLDER, "models", "contactnets_elbow.urdf"), floating_base=True)
    model, params, _ = urdf.build(dt=0.01)
    poses = joint_data.body_poses(model, params, tosses.qpos[:5, -1], tosses.qvel[:5, -1])
    np.testing.assert_allclose(poses["pos"], tosses.pos[:5, -1], atol=1e-6)
    turned = quat_log(quat_multiply(poses["quat"], quat_conjugate(tosses.quat[:5, -1])))
    assert np.abs(turned).max() < 1e-5


def test_forward_only_fit_of_joint_data_reports_bootstrap_errors(scene, tosses):
    model, params, state = scene
    fit = fit_data.fit_measured(model, params, state, tosses.subset(slice(0, 4)), ("plane_friction",), horizons=(),
                                refine_rounds=1, search_width=1.0)
    assert fit.result is None and fit.stages == "rollout search only"
    error = float(np.ravel(fit.standard_errors["plane_friction"])[0])
    assert np.isfinite(error) and error > 0
    assert "forward search only" in fit.table()
    with pytest.raises(ValueError, match="nothing to fit"):
        fit_data.fit_measured(model, params, state, tosses.subset(slice(0, 2)), ("plane_friction",), horizons=(),
                              refine_rounds=0)


def test_the_cli_reads_joint_rows_for_a_scene_with_joints(capsys):
    from jaxrb.cli.main import main

    scene = os.path.join(FOLDER, "fitted_elbow.json")
    assert main(["evaluate", scene, DATA, "--sample-dt", "1/148", "--trajectories", "0:3"]) == 0
    assert "over 3 trajectories" in capsys.readouterr().out
    assert main(["evaluate", scene, DATA, "--trajectories", "0:3"]) == 2
    assert "pass sample_dt" in capsys.readouterr().err
