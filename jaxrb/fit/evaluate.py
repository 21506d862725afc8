"""Score a model on measured trajectories, the way the literature scores simulators.

Protocol (Acosta et al., RA-L 2022, on the DAIR Lab cube tosses): each
trajectory is simulated for its whole length from the state estimated from its
own free-flight samples (:mod:`jaxrb.fit.initial_state`), never re-fed measured
states; sample by sample the position error |p_sim − p_real| is divided by the
body's size and the rotation error is the angle of q_sim q_real⁻¹ in degrees;
each is averaged over the trajectory's samples (sample 0, the estimate itself,
included), then summarised over trajectories: mean ± std, median, 90th
percentile.

Sizes: a box's is its longest edge (2·max half-extent; the cube's width), a
sphere's or circle's its diameter, a capsule's its length tip to tip, any
other shape's its bounding diameter; :func:`body_sizes` gives them and every
function takes ``sizes`` to override.

The rollout of one call is one ``vmap`` over the K trajectories, each padded to
the longest (the padding is simulated but masked out of every error).

Trajectories recorded in joint coordinates (:mod:`jaxrb.fit.joint_data`, the
elbow tosses) follow that data's protocol instead: each starts three samples
before first contact from a state estimated in joint coordinates, is scored
from there, and keeps the tracker's lengths (no calibration).
"""

from __future__ import annotations

import dataclasses
from typing import Callable, Optional

import jax
import jax.numpy as jnp
import numpy as np

from jaxrb.compile import jit
from jaxrb.fit import joint_data
from jaxrb.fit.initial_state import (CLEARANCE, quat_exp, quat_multiply, estimate_initial_states, free_flight_residuals, free_samples,
                                     initial_states, length_scale)
from jaxrb.fit.measured import Trajectories
from jaxrb.fit.observations import quaternion_angle
from jaxrb.model.shapes import Box, Capsule, Sphere
from jaxrb.physics.step import make_step, rollout
from jaxrb.model.types import Model, Params, State


def body_sizes(model: Model) -> np.ndarray:
    """The size of each body that errors are divided by (module docstring).

    Args:
        model: the scene's Model (its shapes).

    Returns:
        (n,) sizes in m.
    """
    sizes = []
    for index, shape in enumerate(model.shapes):
        if isinstance(shape, Box):
            sizes.append(2.0 * max(shape.half_extents))
        elif isinstance(shape, Sphere):
            sizes.append(2.0 * shape.radius)
        elif isinstance(shape, Capsule):
            sizes.append(2.0 * (shape.radius + shape.half_length))
        elif shape is not None and hasattr(shape, "points"):
            points = np.asarray(shape.points, dtype=np.float64)
            sizes.append(2.0 * float(np.max(np.linalg.norm(points - points.mean(0), axis=-1))))
        else:
            raise ValueError(f"body {index} ({model.names[index] if model.names else index}): no shape "
                             "to take a size from; pass sizes=")
    return np.asarray(sizes)


@dataclasses.dataclass(frozen=True)
class Replay:
    """Everything needed to simulate K measured trajectories from their estimated starts.

    Attributes:
        model: the Model.
        step: ``make_step(model)``.
        initial: State with leading axis K, the estimated state at sample 0.
        num_free: (K,) free-flight samples each estimate used.
        trajectories: the measured data, calibrated to true lengths.
        sizes: (n,) body sizes errors are divided by.
        length_scale: the tracker's lengths per true length; position errors
            are multiplied by it, so they are reported in the data's own units.
        every: steps per sample interval (:func:`steps_per_sample`).
        measured: joint-coordinate data only: the trajectories as recorded,
            before ``trajectories`` was cut to start where each simulation
            starts; ``num_free`` then counts their samples before first contact.
    """

    model: Model
    step: Callable
    initial: State
    num_free: np.ndarray
    trajectories: Trajectories
    sizes: np.ndarray
    length_scale: float = 1.0
    every: int = 1
    measured: Optional[Trajectories] = None


def steps_per_sample(params: Params, trajectories: Trajectories) -> int:
    """How many steps of ``params.dt`` make one sample interval; a ValueError unless a whole number.

    Args:
        params: Params (its ``dt``).
        trajectories: the data (its ``sample_dt``).

    Returns:
        k, the steps per sample.

    Build scenes for measured data with ``dt = sample_dt / k`` and
    ``substeps=1``: the rollout then scans single steps and keeps every k-th,
    which compiles one step instead of k unrolled substeps (a penalty cube's
    short-horizon Jacobian: 2.8 s against 32 s to compile, 6x faster to run).
    """
    ratio = trajectories.sample_dt / float(params.dt)
    every = int(round(ratio))
    if every < 1 or abs(ratio - every) > 1e-5 * ratio:  # dt may be float32
        raise ValueError(f"{trajectories.source}: samples are {trajectories.sample_dt:.6g} s apart, not a whole "
                         f"number of the scene's {float(params.dt):.6g} s steps; build it with "
                         f"dt=sample_dt/k, e.g. dt={trajectories.sample_dt / max(every, 1)!r}")
    return every


def calibrated(model: Model, params: Params, trajectories: Trajectories, scale: Optional[float] = None):
    """The data in true lengths, the tracker's length scale measured from free flight unless given.

    See :func:`jaxrb.fit.initial_state.length_scale`; ``scale=1`` keeps the data as it is, as it is
    kept by default for joint-coordinate data (its protocol scores the tracker's lengths).

    Args:
        model, params: the scene, for its collision detection and gravity.
        trajectories: the measured data.
        scale: the scale to use, or None to measure it.

    Returns:
        (trajectories with positions and velocities divided by the scale, scale).
    """
    steps_per_sample(params, trajectories)
    if scale is None and trajectories.qpos is not None:
        scale = 1.0
    if scale is None:
        scale = length_scale(trajectories, free_samples(model, params, trajectories), np.asarray(params.gravity))
    return trajectories.scaled(1.0 / scale), float(scale)


def prepare_replay(model: Model, params: Params, state: State, trajectories: Trajectories, *,
                   clearance: Optional[float] = None, sizes: Optional[np.ndarray] = None,
                   scale: Optional[float] = None) -> Replay:
    """Estimate every trajectory's initial state and bundle what :func:`simulate` needs.

    Args:
        model, params, state: from ``Scene.build(dt=trajectories.sample_dt / k, ...)``.
        trajectories: K measured trajectories of the scene's n bodies.
        clearance: see :func:`jaxrb.fit.initial_state.free_samples`; default
            its ``CLEARANCE``, or ``JOINT_CLEARANCE`` for joint-coordinate data.
        sizes: (n,) sizes to divide position errors by (default :func:`body_sizes`).
        scale: the tracker's length scale (:func:`calibrated`); measured from
            free flight if None, 1 to take the data's lengths as true.

    Returns:
        A :class:`Replay`.
    """
    trajectories, scale = calibrated(model, params, trajectories, scale)
    sizes = body_sizes(model) if sizes is None else np.asarray(sizes, dtype=np.float64)
    common = dict(model=model, step=make_step(model), sizes=sizes, length_scale=scale,
                  every=steps_per_sample(params, trajectories))
    if trajectories.qpos is not None:
        first = joint_data.first_contacts(model, params, trajectories, clearance or joint_data.JOINT_CLEARANCE)
        start, qpos, qvel = joint_data.estimate_joint_starts(model, params, trajectories, first)
        return Replay(initial=joint_data.initial_states(model, params, state, qpos, qvel), num_free=first,
                      trajectories=trajectories.from_samples(start), measured=trajectories, **common)
    num_free = free_samples(model, params, trajectories, clearance or CLEARANCE)
    estimate = estimate_initial_states(trajectories, num_free, np.asarray(params.gravity))
    return Replay(initial=initial_states(state, estimate), num_free=num_free, trajectories=trajectories, **common)


def simulate(step: Callable, params: Params, initial: State, num_samples: int, every: int = 1) -> State:
    """Roll every trajectory out from its initial state; sample 0 is the initial state.

    Args:
        step: the step function.
        params: Params (shared by all trajectories).
        initial: State with leading axis K.
        num_samples: T, samples to produce.
        every: steps per sample interval.

    Returns:
        State with leading axes (K, T).
    """
    def one(start):
        later = rollout(step, start, params, (num_samples - 1) * every, every=every)
        return jax.tree_util.tree_map(lambda first, rest: jnp.concatenate([first[None], rest]), start, later)

    return jax.vmap(one)(initial)


def sample_errors(pos, quat, measured_pos, measured_quat, sizes):
    """Per-sample errors: position in fractions of size and rotation in radians.

    Args:
        pos, measured_pos: (..., n, 3) simulated and measured positions.
        quat, measured_quat: (..., n, 4) simulated and measured unit quaternions.
        sizes: (n,) body sizes.

    Returns:
        (position (...), rotation (...)): each the mean over the n bodies.
    """
    distance = jnp.sqrt(jnp.sum((pos - measured_pos) ** 2, axis=-1) + 1e-30)  # finite gradient at 0
    return jnp.mean(distance / sizes, axis=-1), jnp.mean(quaternion_angle(quat, measured_quat), axis=-1)


def trajectory_errors(pos, quat, trajectories: Trajectories, sizes) -> tuple:
    """Per-trajectory mean errors of simulated poses against the measurements.

    Args:
        pos: (K, T, n, 3) simulated positions, e.g. of :func:`simulate`'s
            States or of another engine.
        quat: (K, T, n, 4) simulated unit quaternions.
        trajectories: the K measured trajectories (T samples padded).
        sizes: (n,) body sizes.

    Returns:
        (position (K,) in % of size, rotation (K,) in degrees), jax arrays.
    """
    pos = jnp.asarray(pos)
    mask = jnp.asarray(trajectories.mask, pos.dtype)
    position, rotation = sample_errors(pos, jnp.asarray(quat, pos.dtype), jnp.asarray(trajectories.pos, pos.dtype),
                                       jnp.asarray(trajectories.quat, pos.dtype), jnp.asarray(sizes, pos.dtype))
    count = jnp.sum(mask, axis=1)
    return (100.0 * jnp.sum(position * mask, 1) / count, jnp.degrees(jnp.sum(rotation * mask, 1) / count))


def error_function(replay: Replay) -> Callable:
    """The protocol's per-trajectory errors as a function of Params, not yet jitted (vmap it).

    Args:
        replay: from :func:`prepare_replay`.

    Returns:
        ``errors(params) -> (position (K,) in % of size, rotation (K,) in degrees)``.
    """
    trajectories, sizes = replay.trajectories, np.asarray(replay.sizes) / replay.length_scale

    def errors(params):
        states = simulate(replay.step, params, replay.initial, trajectories.num_samples, replay.every)
        return trajectory_errors(states.pos, states.quat, trajectories, sizes)

    return errors


def scorer(replay: Replay) -> Callable:
    """:func:`error_function` jitted: compiled once, called with any Params of the same structure.

    Args:
        replay: from :func:`prepare_replay`.

    Returns:
        The jitted ``errors(params)``.
    """
    return jit(error_function(replay))


@dataclasses.dataclass(frozen=True)
class Scores:
    """Per-trajectory protocol errors and their summary.

    Attributes:
        position: (K,) mean position error of each trajectory, % of size.
        rotation: (K,) mean rotation error, degrees.
        ids: (K,) the trajectories' ids.
    """

    position: np.ndarray
    rotation: np.ndarray
    ids: np.ndarray

    def summary(self) -> dict:
        """Mean, std, median and 90th percentile of both errors.

        Returns:
            ``{"position": {...}, "rotation": {...}}``, each with keys mean, std, median, p90.
        """
        out = {}
        for name, values in (("position", self.position), ("rotation", self.rotation)):
            out[name] = {"mean": float(np.mean(values)), "std": float(np.std(values)),
                         "median": float(np.median(values)), "p90": float(np.percentile(values, 90))}
        return out

    def text(self) -> str:
        """One line per error: mean ± std, median, 90th percentile.

        Returns:
            Two lines of text.
        """
        summary = self.summary()
        return "\n".join(f"{name}: {s['mean']:.2f} ± {s['std']:.2f} {unit} (median {s['median']:.2f}, "
                         f"90th percentile {s['p90']:.2f}) over {len(self.ids)} trajectories"
                         for (name, s), unit in zip(summary.items(), ("% of size", "deg")))

    def worst(self, count: int = 5) -> np.ndarray:
        """The trajectories with the largest position error, worst first.

        Args:
            count: how many.

        Returns:
            (count,) their ids.
        """
        return self.ids[np.argsort(-self.position)[:count]]


def score(replay: Replay, params: Params) -> Scores:
    """Protocol errors of ``params`` on the replay's trajectories (compiles once per call).

    Args:
        replay: from :func:`prepare_replay`.
        params: the model's Params.

    Returns:
        :class:`Scores`.
    """
    position, rotation = scorer(replay)(params)
    return Scores(position=np.asarray(position), rotation=np.asarray(rotation), ids=replay.trajectories.ids)


def noise_floor(replay: Replay, params: Params, draws: int = 4, seed: int = 0) -> tuple:
    """How far the tracker's own noise alone moves the prediction: an error no model can remove.

    Each draw adds Gaussian noise of the size the free-flight fit leaves
    (:func:`jaxrb.fit.initial_state.free_flight_residuals`, the median over
    trajectories, per axis and per rotation) to the free samples, estimates
    the initial states again, simulates, and scores the result against the
    simulation from the unperturbed estimate, with the protocol's metric.
    Joint-coordinate data get the noise on their recorded coordinates
    (:func:`jaxrb.fit.joint_data.free_flight_noise`, :func:`~jaxrb.fit.joint_data.perturbed`).

    Args:
        replay: from :func:`prepare_replay`.
        params: the model to perturb.
        draws: noise draws, averaged.
        seed: seed of the noise.

    Returns:
        (:class:`Scores` averaged over draws, position noise (m), rotation noise (rad)).
    """
    data, gravity = replay.trajectories, np.asarray(params.gravity)
    template = jax.tree_util.tree_map(lambda a: a[0], replay.initial)
    if replay.measured is not None:  # joint coordinates: noise on the recorded coordinates
        model = replay.model
        noise = joint_data.free_flight_noise(model, params, replay.measured, replay.num_free)

        def restart(rng):
            noisy = joint_data.perturbed(model, params, replay.measured, *noise, rng)
            _, qpos, qvel = joint_data.estimate_joint_starts(model, params, noisy, replay.num_free)
            return joint_data.initial_states(model, params, template, qpos, qvel)
    else:
        estimate = estimate_initial_states(data, replay.num_free, gravity)
        noise = tuple(float(np.median(r)) for r in free_flight_residuals(data, replay.num_free, estimate, gravity))

        def restart(rng):
            noisy = dataclasses.replace(
                data, pos=data.pos + rng.normal(0.0, noise[0], data.pos.shape),
                quat=quat_multiply(quat_exp(rng.normal(0.0, noise[1] / np.sqrt(3.0), data.pos.shape)), data.quat))
            return initial_states(template, estimate_initial_states(noisy, replay.num_free, gravity))
    position_noise, rotation_noise = noise
    reference = simulate(replay.step, params, replay.initial, data.num_samples, replay.every)
    as_measured = dataclasses.replace(data, pos=np.asarray(reference.pos), quat=np.asarray(reference.quat))
    sizes = np.asarray(replay.sizes) / replay.length_scale

    @jit
    def spread(initial):
        states = simulate(replay.step, params, initial, data.num_samples, replay.every)
        return trajectory_errors(states.pos, states.quat, as_measured, sizes)

    rng = np.random.default_rng(seed)
    position, rotation = [], []
    for _ in range(draws):
        result = spread(restart(rng))
        position.append(np.asarray(result[0]))
        rotation.append(np.asarray(result[1]))
    scores = Scores(position=np.mean(position, 0), rotation=np.mean(rotation, 0), ids=data.ids)
    return scores, position_noise * replay.length_scale, rotation_noise


def plot_scores(scores: Scores, path, title: str = "") -> None:
    """Write a PNG: histograms of both errors with the mean and median marked.

    Args:
        scores: from :func:`score`.
        path: the PNG to write.
        title: the figure's title.
    """
    import matplotlib.pyplot as plt  # the user's backend is left as it is (a notebook's keeps showing figures)

    figure, axes = plt.subplots(1, 2, figsize=(9, 3.4))
    for axis, values, label in ((axes[0], scores.position, "position error (% of size)"),
                                (axes[1], scores.rotation, "rotation error (deg)")):
        axis.hist(values, bins=30, color="0.6")
        axis.axvline(np.mean(values), color="C3", label=f"mean {np.mean(values):.1f}")
        axis.axvline(np.median(values), color="C0", linestyle="--", label=f"median {np.median(values):.1f}")
        axis.set_xlabel(label)
        axis.set_ylabel("trajectories")
        axis.legend(frameon=False)
    figure.suptitle(title or f"{len(scores.ids)} trajectories; worst: {', '.join(map(str, scores.worst()))}")
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)
