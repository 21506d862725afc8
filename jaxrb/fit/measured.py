"""Measured trajectories: the file format, the loader and its checks.

A recording holds K trajectories of the same n bodies, sampled every
``sample_dt`` seconds, of different lengths. On the host they are one
:class:`Trajectories` of padded NumPy arrays ``(K, T, n, ...)`` with
``length`` (K,) saying how many samples of each are real; the padding repeats
each trajectory's last sample, so anything computed on it stays finite, and
:attr:`Trajectories.mask` leaves it out of every error and loss.

Files (``.npz``, NumPy's archive), two layouts:

**jaxrb layout** (:func:`save_trajectories` writes it):

=================  ==============  ===============================================
array              shape           meaning
=================  ==============  ===============================================
``pos``            (N, n, 3)       centre of each body, world frame (m)
``quat``           (N, n, 4)       unit quaternion (w, x, y, z), body to world
``vel``            (N, n, 3)       optional: linear velocity, world frame (m/s)
``angvel``         (N, n, 3)       optional: angular velocity (rad/s)
``start``          (K + 1,) int    trajectory k is samples ``start[k]:start[k+1]``
``sample_dt``      ()              sample spacing (s)
``angvel_frame``   () str          ``"world"`` or ``"body"``: the frame of ``angvel``
``ids``            (K,) int        optional: each trajectory's own number
``qpos``           (N, nq)         optional: joint coordinates, MuJoCo's layout
``qvel``           (N, nv)         optional: joint velocities, MuJoCo's layout
=================  ==============  ===============================================

**state-row layout** (the DAIR Lab cube tosses, ``examples/cube_tosses``):
``states`` (N, 13·n) rows of ``quat, pos, angvel, vel`` per body, ``start``
(K + 1,) and optionally ``toss_id`` (K,). It carries no sample spacing and no
frame, so :func:`load_trajectories` needs ``sample_dt=`` and ``angvel_frame=``
for it (the cube tosses: ``1/148`` and ``"body"``). Articulated bodies recorded
in joint coordinates (the elbow tosses) are read with their model by
:func:`jaxrb.fit.joint_data.load_joint_trajectories`, which adds every body's
pose by the model's kinematics.

Angular velocity is converted to the world frame on loading (the State's
frame). A file that is malformed (a missing or misshapen array, NaN or
infinite values, a quaternion off unit length by more than 1e-3, an empty or
one-sample trajectory) raises a ``ValueError`` naming the file, the
trajectory and the array (with its columns).
"""

from __future__ import annotations

import dataclasses
import os
from typing import Optional, Sequence

import numpy as np

ANGVEL_FRAMES = ("world", "body")
#: Largest accepted | |q| - 1 | of a stored quaternion (then renormalised).
QUAT_NORM_TOLERANCE = 1e-3
#: Columns of one body in the state-row layout.
STATE_ROW_COLUMNS = {"quat": slice(0, 4), "pos": slice(4, 7), "angvel": slice(7, 10), "vel": slice(10, 13)}


@dataclasses.dataclass(frozen=True)
class Trajectories:
    """K measured trajectories of n bodies, padded to a common length T.

    Attributes:
        pos: (K, T, n, 3) positions (m), world frame.
        quat: (K, T, n, 4) unit quaternions (w, x, y, z), body to world.
        vel: (K, T, n, 3) world-frame velocities, or None.
        angvel: (K, T, n, 3) world-frame angular velocities, or None.
        length: (K,) number of real samples of each trajectory (>= 2).
        sample_dt: sample spacing (s).
        ids: (K,) each trajectory's own number (its index in the file by default).
        source: where the data came from, for messages.
        qpos: (K, T, nq) joint coordinates (MuJoCo's layout, hinge angles
            unwrapped), or None for free bodies (:mod:`jaxrb.fit.joint_data`).
        qvel: (K, T, nv) joint velocities, or None.
    """

    pos: np.ndarray
    quat: np.ndarray
    vel: Optional[np.ndarray]
    angvel: Optional[np.ndarray]
    length: np.ndarray
    sample_dt: float
    ids: np.ndarray
    source: str = "trajectories"
    qpos: Optional[np.ndarray] = None
    qvel: Optional[np.ndarray] = None

    @property
    def num_trajectories(self) -> int:
        """K, the number of trajectories."""
        return int(self.pos.shape[0])

    @property
    def num_samples(self) -> int:
        """T, the padded length."""
        return int(self.pos.shape[1])

    @property
    def mask(self) -> np.ndarray:
        """(K, T) bool: True for real samples, False for padding."""
        return np.arange(self.num_samples)[None, :] < self.length[:, None]

    def subset(self, index) -> "Trajectories":
        """Some of the trajectories, padded to their own longest.

        Args:
            index: indices, a slice or a (K,) boolean mask.

        Returns:
            :class:`Trajectories`.
        """
        index = np.arange(self.num_trajectories)[index]
        if index.size == 0:
            raise ValueError(f"{self.source}: subset: no trajectories selected")
        keep = int(self.length[index].max())
        cut = lambda a: None if a is None else a[index, :keep]  # noqa: E731
        return dataclasses.replace(self, pos=cut(self.pos), quat=cut(self.quat), vel=cut(self.vel),
                                   angvel=cut(self.angvel), qpos=cut(self.qpos), qvel=cut(self.qvel),
                                   length=self.length[index], ids=self.ids[index])

    def from_samples(self, first) -> "Trajectories":
        """Each trajectory from its own first sample on, padded to the new longest.

        Args:
            first: (K,) int, the sample each trajectory now starts at (below its length).

        Returns:
            :class:`Trajectories`.
        """
        first = np.asarray(first, dtype=np.int64)
        if first.shape != (self.num_trajectories,) or np.any(first < 0) or np.any(first >= self.length - 1):
            raise ValueError(f"{self.source}: from_samples: need one start per trajectory, each at least 2 "
                             f"samples before its end; got {first!r}")
        length = self.length - first
        index = np.minimum(first[:, None] + np.arange(int(length.max()))[None], self.length[:, None] - 1)
        rows = np.arange(self.num_trajectories)[:, None]
        cut = lambda a: None if a is None else a[rows, index]  # noqa: E731
        return dataclasses.replace(self, pos=cut(self.pos), quat=cut(self.quat), vel=cut(self.vel),
                                   angvel=cut(self.angvel), qpos=cut(self.qpos), qvel=cut(self.qvel),
                                   length=length)

    def scaled(self, factor: float) -> "Trajectories":
        """The same trajectories in another length unit.

        Args:
            factor: what positions and velocities are multiplied by.

        Returns:
            :class:`Trajectories`.
        """
        if self.qpos is not None and factor != 1.0:
            # Which joint coordinates are lengths is the model's to say; the protocols that record joint
            # coordinates (the elbow tosses) score the data as it is.
            raise ValueError(f"{self.source}: joint-coordinate trajectories are not rescaled; use scale=1")
        return dataclasses.replace(self, pos=self.pos * factor, vel=None if self.vel is None else self.vel * factor)

    def split(self, fraction: float = 0.5, seed: int = 0):
        """A reproducible random split into (first, second) of about ``fraction`` and the rest.

        Args:
            fraction: share of trajectories in the first part, in (0, 1).
            seed: seed of the permutation.

        Returns:
            Two :class:`Trajectories`.
        """
        if not 0.0 < fraction < 1.0:
            raise ValueError(f"split: fraction must be in (0, 1), got {fraction!r}")
        order = np.random.default_rng(seed).permutation(self.num_trajectories)
        cut = min(max(int(round(fraction * self.num_trajectories)), 1), self.num_trajectories - 1)
        return self.subset(np.sort(order[:cut])), self.subset(np.sort(order[cut:]))


def rotate_vectors(quat, vectors, inverse=False):
    """Rotate vectors by unit quaternions (or by their inverses), in NumPy.

    Args:
        quat: (..., 4) unit quaternions (w, x, y, z), body to world.
        vectors: (..., 3) the vectors.
        inverse: rotate by the inverse (world to body).

    Returns:
        (..., 3) the rotated vectors.
    """
    w, axis = quat[..., :1], quat[..., 1:]
    if inverse:
        axis = -axis
    twice = 2.0 * np.cross(axis, vectors)
    return vectors + w * twice + np.cross(axis, twice)


def make_trajectories(pieces: Sequence[dict], sample_dt: float, *, angvel_frame: str = "world",
                      ids: Optional[Sequence[int]] = None, source: str = "trajectories") -> Trajectories:
    """Check and pad a list of trajectories given as arrays.

    Args:
        pieces: one dict per trajectory with ``pos`` (L, n, 3) and ``quat``
            (L, n, 4), optionally ``vel`` and ``angvel`` (L, n, 3) and
            ``qpos`` (L, nq), ``qvel`` (L, nv); every trajectory must have
            the same optional arrays and body count.
        sample_dt: sample spacing (s), > 0.
        angvel_frame: ``"world"`` or ``"body"``, the frame of ``angvel``.
        ids: (K,) the trajectories' own numbers (default 0..K-1).
        source: name used in error messages (a file path).

    Returns:
        :class:`Trajectories` (angular velocity in the world frame).

    Raises:
        ValueError: naming ``source``, the trajectory and the array for any
            malformed input.
    """
    if angvel_frame not in ANGVEL_FRAMES:
        raise ValueError(f"{source}: unknown angvel_frame {angvel_frame!r}; valid: 'world', 'body'")
    if not (np.isfinite(sample_dt) and sample_dt > 0):
        raise ValueError(f"{source}: sample_dt must be a positive number of seconds, got {sample_dt!r}")
    if len(pieces) == 0:
        raise ValueError(f"{source}: no trajectories")
    ids = np.arange(len(pieces)) if ids is None else np.asarray(ids)
    if ids.shape != (len(pieces),):
        raise ValueError(f"{source}: ids: expected shape ({len(pieces)},), got {ids.shape}")
    optional = [name for name in ("vel", "angvel") if pieces[0].get(name) is not None]
    coordinates = [name for name in ("qpos", "qvel") if pieces[0].get(name) is not None]
    width = {"pos": 3, "quat": 4, "vel": 3, "angvel": 3}
    checked = []
    num_bodies = None
    for k, piece in enumerate(pieces):
        where = f"{source}: trajectory {k} (id {ids[k]})"
        arrays = {}
        for name in ("pos", "quat", *optional):
            value = piece.get(name)
            if value is None:
                raise ValueError(f"{where}: array '{name}' is missing (trajectory 0 has it)")
            value = np.asarray(value, dtype=np.float64)
            if value.ndim == 2:
                value = value[:, None, :]
            if value.ndim != 3 or value.shape[-1] != width[name]:
                raise ValueError(f"{where}: '{name}' must have shape (samples, bodies, {width[name]}), "
                                 f"got {value.shape}")
            arrays[name] = value
        for name in coordinates:
            value = np.asarray(piece.get(name, np.empty((0, 0))), dtype=np.float64)
            columns = np.shape(pieces[0][name])[-1]
            if value.ndim != 2 or value.shape != (len(arrays["pos"]), columns):
                raise ValueError(f"{where}: '{name}' must have shape ({len(arrays['pos'])}, {columns}), "
                                 f"got {value.shape}")
            bad = np.argwhere(~np.isfinite(value))
            if bad.size:
                raise ValueError(f"{where}: '{name}' sample {bad[0][0]}, column {bad[0][1]}: not a finite number")
            arrays[name] = value
        lengths = {value.shape[0] for value in arrays.values()}
        bodies = {value.shape[1] for name, value in arrays.items() if name not in coordinates}
        if len(lengths) != 1 or len(bodies) != 1:
            raise ValueError(f"{where}: arrays disagree in samples or bodies: "
                             + ", ".join(f"{n} {v.shape}" for n, v in arrays.items()))
        length, = lengths
        if length < 2:
            raise ValueError(f"{where}: has {length} samples; a trajectory needs at least 2")
        if num_bodies is None:
            num_bodies = bodies.pop()
        elif bodies.pop() != num_bodies:
            raise ValueError(f"{where}: has {arrays['pos'].shape[1]} bodies, trajectory 0 has {num_bodies}")
        for name, value in arrays.items():
            if name in coordinates:
                continue
            bad = ~np.isfinite(value)
            if bad.any():
                sample, body, column = np.argwhere(bad)[0]
                raise ValueError(f"{where}: '{name}' sample {sample}, body {body}, column {column}: "
                                 f"not a finite number ({value[sample, body, column]})")
        norm = np.linalg.norm(arrays["quat"], axis=-1)
        off = np.abs(norm - 1.0)
        if off.max() > QUAT_NORM_TOLERANCE:
            sample, body = np.unravel_index(np.argmax(off), off.shape)
            raise ValueError(f"{where}: 'quat' sample {sample}, body {body}: not a unit quaternion "
                             f"(norm {norm[sample, body]:.6g}; columns are w, x, y, z)")
        arrays["quat"] = arrays["quat"] / norm[..., None]
        if angvel_frame == "body" and "angvel" in arrays:
            arrays["angvel"] = rotate_vectors(arrays["quat"], arrays["angvel"])
        checked.append(arrays)
    length = np.array([a["pos"].shape[0] for a in checked])
    longest = int(length.max())

    def padded(name):
        if name not in checked[0]:
            return None
        out = np.empty((len(checked), longest) + checked[0][name].shape[1:])
        for k, arrays in enumerate(checked):
            value = arrays[name]
            out[k, :len(value)] = value
            out[k, len(value):] = value[-1]
        return out

    return Trajectories(pos=padded("pos"), quat=padded("quat"), vel=padded("vel"), angvel=padded("angvel"),
                        length=length, sample_dt=float(sample_dt), ids=ids, source=source,
                        qpos=padded("qpos"), qvel=padded("qvel"))


def _read_npz(source: str) -> dict:
    """The arrays of a ``.npz`` file; a ValueError naming it if it cannot be read."""
    try:
        return dict(np.load(source, allow_pickle=False))
    except (OSError, ValueError) as error:
        raise ValueError(f"{source}: not a readable .npz file ({error})") from None


def _require(data, name, source):
    if name not in data:
        raise ValueError(f"{source}: array '{name}' is missing (arrays present: {', '.join(sorted(data))})")
    return np.asarray(data[name])


def _check_start(start, num_rows, source):
    if start.ndim != 1 or start.size < 2 or not np.issubdtype(start.dtype, np.integer):
        raise ValueError(f"{source}: 'start' must be a 1-D integer array of K + 1 offsets, got "
                         f"{start.dtype} {start.shape}")
    if start[0] != 0 or start[-1] != num_rows or np.any(np.diff(start) < 0):
        raise ValueError(f"{source}: 'start' must rise from 0 to the number of samples ({num_rows}), got "
                         f"{start[:3].tolist()}...{start[-2:].tolist()}")
    empty = np.flatnonzero(np.diff(start) == 0)
    if empty.size:
        raise ValueError(f"{source}: trajectory {empty[0]}: empty (start[{empty[0]}] == start[{empty[0] + 1}])")


def load_trajectories(path, *, sample_dt: Optional[float] = None,
                      angvel_frame: Optional[str] = None) -> Trajectories:
    """Read a ``.npz`` file of measured trajectories (either layout of the module docstring).

    Args:
        path: the file.
        sample_dt: sample spacing (s): required for the state-row layout; for
            the jaxrb layout it must agree with the file's, if given.
        angvel_frame: ``"world"`` or ``"body"``, as for ``sample_dt``.

    Returns:
        :class:`Trajectories`, angular velocity in the world frame.

    Raises:
        ValueError: naming the file, trajectory and array (and column) of
            anything malformed, or a missing ``sample_dt``/``angvel_frame``.
    """
    source = os.fspath(path)
    data = _read_npz(source)
    start = _require(data, "start", source)
    if "states" in data:
        states = np.asarray(data["states"])
        if states.ndim != 2 or states.shape[1] == 0 or states.shape[1] % 13:
            raise ValueError(f"{source}: 'states' must have 13 columns per body (quat 0-3, pos 4-6, "
                             f"angvel 7-9, vel 10-12), got shape {states.shape}")
        for name, value in (("sample_dt", sample_dt), ("angvel_frame", angvel_frame)):
            if value is None:
                raise ValueError(f"{source}: the state-row layout does not record {name}; pass "
                                 f"load_trajectories(..., {name}=...) (cube tosses: sample_dt=1/148, "
                                 "angvel_frame='body')")
        _check_start(start, states.shape[0], source)
        rows = states.reshape(states.shape[0], -1, 13)
        columns = {name: rows[..., cut] for name, cut in STATE_ROW_COLUMNS.items()}
        ids = data.get("toss_id", data.get("ids"))
    else:
        columns = {name: np.asarray(data[name]) for name in ("pos", "quat", "vel", "angvel", "qpos", "qvel")
                   if name in data}
        for name in ("pos", "quat"):
            _require(data, name, source)
        stored = {"sample_dt": float(_require(data, "sample_dt", source)),
                  "angvel_frame": str(_require(data, "angvel_frame", source))}
        for name, given in (("sample_dt", sample_dt), ("angvel_frame", angvel_frame)):
            if given is not None and given != stored[name]:
                raise ValueError(f"{source}: {name}={given!r} given, but the file says {stored[name]!r}")
        sample_dt, angvel_frame = stored["sample_dt"], stored["angvel_frame"]
        _check_start(start, columns["pos"].shape[0], source)
        ids = data.get("ids")
    pieces = [{name: value[start[k]:start[k + 1]] for name, value in columns.items()}
              for k in range(start.size - 1)]
    return make_trajectories(pieces, sample_dt, angvel_frame=angvel_frame, ids=ids, source=source)


def save_trajectories(path, trajectories: Trajectories) -> None:
    """Write ``trajectories`` in the jaxrb layout (angular velocity in the world frame).

    Args:
        path: the ``.npz`` file to write.
        trajectories: what to write; padding is dropped.
    """
    keep = trajectories.mask
    flat = lambda a: None if a is None else a[keep]  # noqa: E731  (K, T, ...) -> (N, ...)
    arrays = {"pos": flat(trajectories.pos), "quat": flat(trajectories.quat),
              "start": np.concatenate([[0], np.cumsum(trajectories.length)]).astype(np.int64),
              "sample_dt": np.float64(trajectories.sample_dt), "angvel_frame": np.str_("world"),
              "ids": np.asarray(trajectories.ids, dtype=np.int64)}
    for name in ("vel", "angvel", "qpos", "qvel"):
        if getattr(trajectories, name) is not None:
            arrays[name] = flat(getattr(trajectories, name))
    np.savez(path, **arrays)
