"""Measured articulated bodies in joint coordinates: the file layout, body poses, initial states.

Trackers of articulated objects record a floating base and joint angles (the
DAIR Lab elbow tosses: link 1's pose and velocity, then the hinge's angle and
rate). Every other part of :mod:`jaxrb.fit` works on bodies' poses, so
:func:`load_joint_trajectories` reads the coordinates, converts them to
MuJoCo's ``qpos``/``qvel`` layout and adds each body's pose and velocity by
the model's own kinematics (:func:`jaxrb.joints.set_qpos_qvel`): the model
says where link 2 is, so its geometry must be the tracker's.

**Joint-row layout** (``.npz``, dair_pll's state order for a floating base
with 1-dof joints): ``states`` (N, nq + nv) rows of

=====================  =====================================================
columns                quantity
=====================  =====================================================
0–3                    base orientation (w, x, y, z), body to world
4–6                    base frame origin (m), world frame
7 … 7 + J − 1          the J hinge angles (rad, may wrap) or slide lengths
next 3                 base angular velocity (``angvel_frame``)
next 3                 base frame origin's velocity, world frame
last J                 joint rates
=====================  =====================================================

with ``start`` (K + 1,) and optionally ``toss_id`` (K,) as in
:mod:`jaxrb.fit.measured`. Hinge angles are unwrapped per trajectory (the
elbow's tracker wraps them to [−π, π]).

**Initial states** (the elbow data's protocol, the cube protocol carried to
joints; :func:`estimate_joint_starts`): with c the first sample where
anything is within ``clearance`` (20 mm) of touching, the simulation starts at
s = max(0, c − 3) from the measured pose there, with velocities estimated
from the free samples 0 … c − 1: the base's body-frame angular velocity and
the joint rates as slopes of least-squares lines through samples s − 2 …
s + 2 (clipped to the free ones) of log(q_base(s)⁻¹ q_base(j)) and of the
coordinates; the centre of mass's velocity from a ballistic least-squares
fit over all free samples; the base's linear velocity whatever makes the
bodies' centre of mass move so. Trajectories with fewer than 5 free samples
keep their measured state at s. Scoring then runs from s to the end
(:meth:`jaxrb.fit.measured.Trajectories.from_samples`).
"""

from __future__ import annotations

import dataclasses
import functools
import os

import jax
import jax.numpy as jnp
import numpy as np

from jaxrb.fit.initial_state import free_samples, quat_conjugate, quat_log, quat_multiply
from jaxrb.fit.measured import (ANGVEL_FRAMES, Trajectories, _check_start, _read_npz, _require,
                                make_trajectories, rotate_vectors)
from jaxrb.model.types import Model, Params, State
from jaxrb.physics.joints.coordinates import set_qpos_qvel

#: Clearance (m) that marks first contact: a tossed elbow's lowest corner drops up to 18 mm between
#: two 148 Hz samples, so a tighter one misses impacts (the data README's protocol).
JOINT_CLEARANCE = 0.02
#: Samples before first contact at which the simulation starts.
SAMPLES_BEFORE_CONTACT = 3
#: Half-width (samples) of the line fits for angular velocity and joint rates.
RATE_HALF_WINDOW = 2
#: Fewest free samples for estimated velocities; below it the measured ones are kept.
MIN_ESTIMATE_SAMPLES = 5


def _floating_base_joints(model: Model, source: str) -> np.ndarray:
    """qpos indices of the 1-dof joints after a free base; a ValueError for any other tree."""
    tree = model.joints
    if tree is None or not tree.joint_kind or tree.joint_kind[0] != "free" or tree.qpos_adr[0] != 0:
        raise ValueError(f"{source}: joint-coordinate data needs a model whose first joint is a free joint "
                         "(the floating base; load a URDF with floating_base=True)")
    others = [(name, kind) for name, kind in zip(tree.joint_names[1:], tree.joint_kind[1:])
              if kind not in ("hinge", "slide")]
    if others:
        raise ValueError(f"{source}: joint {others[0][0]!r} is a {others[0][1]} joint; joint-coordinate data "
                         "takes a free base with hinge and slide joints only")
    return np.arange(7, tree.nq)


@functools.lru_cache(maxsize=8)
def _kinematics_reader(model: Model):
    """``read(params, qpos (B, nq), qvel (B, nv)) -> State`` (B bodies' read-outs), jitted once per Model:
    the estimate, the noise floor and loading call it many times."""

    def read(params, qpos, qvel):
        template = State(pos=jnp.zeros((model.num_bodies, 3), params.mass.dtype), vel=None, angvel=None,
                         quat=None, angle=None, time=jnp.zeros((), params.mass.dtype))
        return set_qpos_qvel(model, params, template, qpos, qvel)

    return jax.jit(jax.vmap(read, in_axes=(None, 0, 0)))


def body_poses(model: Model, params: Params, qpos, qvel) -> dict:
    """Every body's pose and velocity at the given coordinates, by the model's kinematics.

    Args:
        model, params: the scene (its joint tree and ``com_offset``).
        qpos: (..., nq) coordinates; qvel: (..., nv) velocities (MuJoCo's layout).

    Returns:
        NumPy float64 arrays ``pos``, ``vel``, ``angvel`` (..., n, 3) (world
        frame, centres of mass) and ``quat`` (..., n, 4).
    """
    qpos, qvel = np.asarray(qpos, np.float64), np.asarray(qvel, np.float64)
    batch = qpos.shape[:-1]
    state = _kinematics_reader(model)(params, qpos.reshape(-1, qpos.shape[-1]), qvel.reshape(-1, qvel.shape[-1]))
    return {name: np.asarray(getattr(state, name), np.float64).reshape(batch + getattr(state, name).shape[1:])
            for name in ("pos", "quat", "vel", "angvel")}


def load_joint_trajectories(path, model: Model, params: Params, *, sample_dt: float,
                            angvel_frame: str = "body") -> Trajectories:
    """Read joint-row trajectories (module docstring) and add every body's pose by ``model``'s kinematics.

    Args:
        path: the ``.npz`` file.
        model, params: a 3D scene whose first joint is a free base followed
            by hinge or slide joints, as many as the rows hold.
        sample_dt: sample spacing (s); the rows do not record it (elbow tosses: 1/148).
        angvel_frame: frame of the base's angular velocity, ``"body"`` (dair_pll's) or ``"world"``.

    Returns:
        :class:`~jaxrb.fit.measured.Trajectories` with ``qpos``/``qvel``
        (hinge angles unwrapped) and the bodies' ``pos``, ``quat``, ``vel``
        and ``angvel`` (world frame).

    Raises:
        ValueError: naming the file, and the trajectory and column, for
            malformed data, or naming what the model lacks.
    """
    source = os.fspath(path)
    if angvel_frame not in ANGVEL_FRAMES:
        raise ValueError(f"{source}: unknown angvel_frame {angvel_frame!r}; valid: 'world', 'body'")
    coordinates = _floating_base_joints(model, source)
    tree = model.joints
    data = _read_npz(source)
    states, start = np.asarray(_require(data, "states", source)), _require(data, "start", source)
    joints = coordinates.size
    if states.ndim != 2 or states.shape[1] != tree.nq + tree.nv:
        raise ValueError(f"{source}: 'states' must have {tree.nq + tree.nv} columns for this model (quat 0-3, "
                         f"pos 4-6, {joints} joint coordinates, angvel, vel, {joints} joint rates), got shape "
                         f"{states.shape}")
    _check_start(start, states.shape[0], source)
    bad = np.argwhere(~np.isfinite(states))
    if bad.size:
        row, column = bad[0]
        k = int(np.searchsorted(start, row, side="right") - 1)
        raise ValueError(f"{source}: trajectory {k}: 'states' sample {row - start[k]}, column {column}: "
                         "not a finite number")
    quat = states[:, 0:4]
    norm = np.linalg.norm(quat, axis=-1)
    if np.abs(norm - 1.0).max() > 1e-3:
        row = int(np.argmax(np.abs(norm - 1.0)))
        k = int(np.searchsorted(start, row, side="right") - 1)
        raise ValueError(f"{source}: trajectory {k}: 'states' sample {row - start[k]}, columns 0-3: not a unit "
                         f"quaternion (norm {norm[row]:.6g}; columns are w, x, y, z)")
    quat = quat / norm[:, None]
    velocity = states[:, tree.nq:]
    angvel = velocity[:, 0:3] if angvel_frame == "body" else rotate_vectors(quat, velocity[:, 0:3], inverse=True)
    qpos = np.concatenate([states[:, 4:7], quat, states[:, 7:tree.nq]], axis=1)
    qvel = np.concatenate([velocity[:, 3:6], angvel, velocity[:, 6:]], axis=1)
    hinges = [tree.qpos_adr[j] for j, kind in enumerate(tree.joint_kind) if kind == "hinge"]
    pieces = []
    for k in range(start.size - 1):
        piece_qpos = qpos[start[k]:start[k + 1]].copy()
        if hinges:
            piece_qpos[:, hinges] = np.unwrap(piece_qpos[:, hinges], axis=0)
        pieces.append({"qpos": piece_qpos, "qvel": qvel[start[k]:start[k + 1]]})
    poses = body_poses(model, params, np.concatenate([p["qpos"] for p in pieces]), qvel)
    for k, piece in enumerate(pieces):
        piece.update({name: value[start[k]:start[k + 1]] for name, value in poses.items()})
    return make_trajectories(pieces, sample_dt, ids=data.get("toss_id", data.get("ids")), source=source)


def _line_fit(time, values):
    """Least-squares line through ``values`` (F, m) against ``time`` (F,): (fitted values (F, m), slope (m,))."""
    design = np.stack([np.ones_like(time), time], axis=1)
    coefficients = np.linalg.lstsq(design, values, rcond=None)[0]
    return design @ coefficients, coefficients[1]


def _centre_of_mass(params: Params, pos):
    """(..., 3) mass-weighted mean of the bodies' centres ``pos`` (..., n, 3)."""
    mass = np.asarray(params.mass, np.float64)
    return np.einsum("...nd,n->...d", pos, mass / mass.sum())


def _base_turns(trajectories: Trajectories, k: int, start: int, window):
    """(F, 3) body-frame rotation vectors log(q_base(start)⁻¹ q_base(j)) of trajectory k over the samples ``window``."""
    base = trajectories.qpos[k, :, 3:7]
    return quat_log(quat_multiply(quat_conjugate(base[start])[None], base[window]))


def estimate_joint_starts(model: Model, params: Params, trajectories: Trajectories, first_contact) -> tuple:
    """The protocol's start sample and state of each trajectory (module docstring).

    Args:
        model, params: the scene (masses weigh the centre of mass; gravity the ballistic fit).
        trajectories: K joint-coordinate trajectories.
        first_contact: (K,) c, the first sample near contact (:func:`first_contacts`).

    Returns:
        (start (K,) int, qpos (K, nq), qvel (K, nv)): the start sample and the estimated state there.
    """
    _floating_base_joints(model, trajectories.source)
    dt, gravity = trajectories.sample_dt, np.asarray(params.gravity, np.float64)
    com = _centre_of_mass(params, trajectories.pos)  # (K, T, 3)
    first_contact = np.asarray(first_contact, dtype=np.int64)
    start = np.maximum(0, first_contact - SAMPLES_BEFORE_CONTACT)
    rows = np.arange(trajectories.num_trajectories)
    qpos, qvel = trajectories.qpos[rows, start].copy(), trajectories.qvel[rows, start].copy()
    com_vel = np.zeros((rows.size, 3))
    estimated = first_contact >= MIN_ESTIMATE_SAMPLES
    for k in np.flatnonzero(estimated):
        s, c = int(start[k]), int(first_contact[k])
        window = np.arange(max(0, s - RATE_HALF_WINDOW), min(c - 1, s + RATE_HALF_WINDOW) + 1)
        time = (window - s) * dt
        qvel[k, 3:6] = _line_fit(time, _base_turns(trajectories, k, s, window))[1]
        qvel[k, 6:] = _line_fit(time, trajectories.qpos[k, window, 7:])[1]
        free_time = (np.arange(c) - s) * dt
        com_vel[k] = _line_fit(free_time, com[k, :c] - 0.5 * free_time[:, None] ** 2 * gravity)[1]
    # The base's linear velocity adds to every body's: it is the centre of mass's, less what the
    # rotations and joint rates give it.
    still = qvel.copy()
    still[:, 0:3] = 0.0
    moved = body_poses(model, params, qpos, still)["vel"]  # (K, n, 3)
    qvel[estimated, 0:3] = (com_vel - _centre_of_mass(params, moved))[estimated]
    return start, qpos, qvel


def first_contacts(model: Model, params: Params, trajectories: Trajectories,
                   clearance: float = JOINT_CLEARANCE) -> np.ndarray:
    """c of each trajectory: its first sample with anything within ``clearance`` of touching (at least 2).

    Args:
        model, params: the scene (its collision detection runs on the measured poses).
        trajectories: K trajectories.
        clearance: distance (m); :data:`JOINT_CLEARANCE` by default.

    Returns:
        (K,) int.
    """
    return free_samples(model, params, trajectories, clearance)


def initial_states(model: Model, params: Params, template: State, qpos, qvel) -> State:
    """A batched State (leading axis K) at the coordinates ``qpos`` (K, nq), ``qvel`` (K, nv).

    Args:
        model, params: the scene.
        template: a one-world State from ``Scene.build`` (its other fields are kept).
        qpos, qvel: the coordinates, e.g. from :func:`estimate_joint_starts`.

    Returns:
        State with a leading axis K.
    """
    dtype = template.pos.dtype
    return jax.vmap(lambda q, v: set_qpos_qvel(model, params, template, q, v))(
        jnp.asarray(qpos, dtype), jnp.asarray(qvel, dtype))


def free_flight_noise(model: Model, params: Params, trajectories: Trajectories, first_contact) -> tuple:
    """The tracker's noise as the protocol's fits see it, for :func:`jaxrb.fit.evaluate.noise_floor`.

    Position: the RMS per axis of the centre of mass's residual from its
    ballistic fit over the free samples. Rotation: the RMS angle of the base's
    residual from the line fits of its rotation over each start's window,
    scaled up for the line's two fitted parameters per axis. Medians over the
    trajectories with at least :data:`MIN_ESTIMATE_SAMPLES` free samples.

    Args:
        model, params: the scene.
        trajectories: the joint-coordinate trajectories as recorded.
        first_contact: (K,) their first samples near contact.

    Returns:
        (position noise (m), rotation noise (rad)).
    """
    dt, gravity = trajectories.sample_dt, np.asarray(params.gravity, np.float64)
    com = _centre_of_mass(params, trajectories.pos)
    position, rotation = [], []
    for k, c in enumerate(np.asarray(first_contact)):
        if c < MIN_ESTIMATE_SAMPLES:
            continue
        time = np.arange(c) * dt
        heights = com[k, :c] - 0.5 * time[:, None] ** 2 * gravity
        fitted = _line_fit(time, heights)[0]
        position.append(np.sqrt(np.mean((fitted - heights) ** 2) * c / (c - 2)))
        s = max(0, c - SAMPLES_BEFORE_CONTACT)
        window = np.arange(max(0, s - RATE_HALF_WINDOW), c)
        turned = _base_turns(trajectories, k, s, window)
        fitted = _line_fit((window - s) * dt, turned)[0]
        rotation.append(np.sqrt(np.mean(np.sum((fitted - turned) ** 2, -1)) * window.size / (window.size - 2)))
    return float(np.median(position)), float(np.median(rotation))


def perturbed(model: Model, params: Params, trajectories: Trajectories, position_noise: float,
              rotation_noise: float, rng: np.random.Generator) -> Trajectories:
    """The trajectories with Gaussian noise on the recorded coordinates, the bodies' poses recomputed.

    The base's position gets ``position_noise`` per axis, its orientation a
    rotation of ``rotation_noise`` RMS angle, each joint coordinate
    ``rotation_noise`` (a hinge's angle; a slide's length gets ``position_noise``).

    Args:
        model, params: the scene.
        trajectories: joint-coordinate trajectories.
        position_noise, rotation_noise: the noise (m, rad), e.g. of :func:`free_flight_noise`.
        rng: the random generator.

    Returns:
        :class:`~jaxrb.fit.measured.Trajectories`.
    """
    tree = model.joints
    qpos = trajectories.qpos.copy()
    shape = qpos.shape[:-1]
    qpos[..., 0:3] += rng.normal(0.0, position_noise, shape + (3,))
    turn = rng.normal(0.0, rotation_noise / np.sqrt(3.0), shape + (3,))
    angle = np.linalg.norm(turn, axis=-1, keepdims=True)
    qpos[..., 3:7] = quat_multiply(qpos[..., 3:7], np.concatenate(
        [np.cos(angle / 2), turn * np.sinc(angle / (2 * np.pi)) / 2], axis=-1))
    for kind, address in zip(tree.joint_kind[1:], tree.qpos_adr[1:]):
        qpos[..., address] += rng.normal(0.0, rotation_noise if kind == "hinge" else position_noise, shape)
    poses = body_poses(model, params, qpos, trajectories.qvel)
    return dataclasses.replace(trajectories, qpos=qpos, **poses)
