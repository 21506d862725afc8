"""Measured trajectories in, fitted physical model out: the workflow behind ``jaxrb fit``.

1. The scene is built with a whole number of steps per sample interval
   (:func:`jaxrb.fit.evaluate.steps_per_sample`).
2. The tracker's length scale is calibrated from free flight
   (:func:`jaxrb.fit.initial_state.length_scale`): positions are divided by it, so
   the physics keeps its true gravity and sizes; errors are reported back in
   the data's own units.
3. The chosen ``Params`` fields are fitted by Levenberg–Marquardt
   (:mod:`jaxrb.fit.least_squares`) to short-horizon prediction errors
   (:mod:`jaxrb.fit.shooting`), from the best of a few starting points, a short
   horizon then a longer one, within a time budget, with robust standard
   errors and a per-parameter check of whether the data agree on the
   gradient's sign.
4. A forward-only pattern search refines the result on what it is judged
   by: full rollouts from each trajectory's free-flight estimate
   (:mod:`jaxrb.fit.evaluate`). On the cube tosses the short horizons' friction
   was 5-15 % above the full rollouts' best (8 samples: μ 0.209, 32: 0.195,
   full rollouts: 0.175-0.18), and the protocol error is V-shaped and sharp
   in μ (0.01 off costs about 2 % of the cube's width).

:func:`fitted_scene` writes the result back as a scene file that
``rb.load_scene`` and ``jaxrb run`` read.
"""

from __future__ import annotations

import dataclasses
import math
import os
import time
import warnings
from typing import Callable, Optional, Sequence

import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree

from jaxrb.fit import evaluate

from jaxrb.fit import least_squares

from jaxrb.fit import shooting
from jaxrb.fit.evaluate import body_sizes, calibrated
from jaxrb.fit.joint_data import load_joint_trajectories
from jaxrb.fit.measured import Trajectories, load_trajectories
from jaxrb.fit.parameter_transforms import DEFAULT_TRANSFORMS, from_unconstrained, to_unconstrained
from jaxrb.files.scenefile import SceneFile, load_scene, scene_to_dict
from jaxrb.physics.step import make_step
from jaxrb.model.types import Model, Params, State

#: Params fields that a scene file holds per body, per plane, or as a build option.
BODY_FIELDS = ("mass", "friction", "restitution", "linear_damping", "angular_damping")
PLANE_FIELDS = {"plane_friction": "friction", "plane_restitution": "restitution"}
BUILD_FIELDS = ("contact_margin", "bounce_threshold", "contact_hertz", "contact_damping_ratio",
                "max_push_velocity", "penalty_stiffness", "penalty_damping", "penalty_width",
                "friction_velocity", "impulse_smoothing")
#: Shape-dict entries that are lengths (multiplied by a fitted shape_scale when written).
SHAPE_LENGTHS = ("radius", "half_length", "half_extents", "vertices")
FITTABLE = BODY_FIELDS + tuple(PLANE_FIELDS) + BUILD_FIELDS + ("inertia", "shape_scale")


@dataclasses.dataclass
class DataFit:
    """A fit of Params fields to measured trajectories.

    Attributes:
        params: the fitted Params.
        fields: the fitted field names.
        standard_errors: {field: array like the field} standard errors of the
            final values: of the rollout loss's minimum when the rollout search
            ran (:func:`jaxrb.fit.least_squares.bootstrap_errors`), else the last
            LM stage's robust ones.
        reliability: {field: array} gradient signal-to-noise where the last
            LM stage started (:func:`jaxrb.fit.least_squares.gradient_reliability`);
            below 2 the trajectories disagree on which way the field should move.
        result: the last LM stage's :class:`~jaxrb.fit.least_squares.LeastSquaresResult`,
            None when the fit was the rollout search alone.
        length_scale: the tracker's lengths per true length used.
        seconds: wall time of the fit, compile included.
        path: one dict per LM iteration and rollout-search round, in order:
            ``stage`` (e.g. ``"horizon 8"``), ``cost`` (that stage's), and
            each fitted field's value (flattened).
    """

    params: Params
    fields: tuple
    standard_errors: dict
    reliability: dict
    result: Optional[least_squares.LeastSquaresResult]
    length_scale: float
    seconds: float
    path: list = dataclasses.field(default_factory=list)

    @property
    def stages(self) -> str:
        """How the fit went, in words: its LM iterations and why they stopped, or the rollout search alone."""
        if self.result is None:
            return "rollout search only"
        return f"{self.result.iterations} LM iterations, {self.result.stopped}"

    def table(self) -> str:
        """One line per fitted field: value ± standard error, gradient signal-to-noise.

        Returns:
            The lines, and each body–plane pair's mixed friction when friction was fitted.
        """
        lines = []
        for name in self.fields:
            value = np.ravel(np.asarray(getattr(self.params, name)))
            error = np.ravel(self.standard_errors[name])
            snr = np.ravel(self.reliability[name])
            for i in range(value.size):
                label = name if value.size == 1 else f"{name}[{i}]"
                judged = ("forward search only" if np.isnan(snr[i]) else
                          f"gradient signal/noise {snr[i]:.2g}{', unreliable' if snr[i] < 2 else ''}")
                lines.append(f"{label:>22s} = {value[i]:.5g} ± {error[i]:.2g}  ({judged})")
        if {"friction", "plane_friction"} & set(self.fields):
            # Contacts mix √(μ_body μ_plane): only the product is identified, so fit one side and
            # read the pair's coefficient here.
            mixed = np.sqrt(np.outer(np.asarray(self.params.friction), np.asarray(self.params.plane_friction)))
            lines += [f"{'pair friction':>22s}   body {i} on plane {j}: {mixed[i, j]:.4g}"
                      for i in range(mixed.shape[0]) for j in range(mixed.shape[1])]
        return "\n".join(lines)


def build_for_data(scene_path, trajectories: Trajectories):
    """Load a scene file and build it for measured data: k single steps per sample interval.

    ``dt = sample spacing / k`` and ``substeps = 1``, with k the fewest that
    makes a step no longer than the file's ``dt / substeps`` (a scene written
    for 1 ms steps keeps steps of at most 1 ms), in float32 unless the file
    names a dtype; the file's other options stay, and ``scene_file`` keeps
    them unchanged for :func:`fitted_scene`. A scan of single steps compiles
    far faster than unrolled substeps (:func:`jaxrb.fit.evaluate.steps_per_sample`).

    Args:
        scene_path: a ``.json`` scene or MJCF file.
        trajectories: the data (its ``sample_dt``).

    Returns:
        (scene file, model, params, state).
    """
    scene_file = load_scene(scene_path)
    options = scene_file.build_options
    step = options.get("dt", trajectories.sample_dt) / options.get("substeps", 1)
    every = max(1, math.ceil(trajectories.sample_dt / step - 1e-9))
    model, params, state = scene_file.build(dt=trajectories.sample_dt / every, substeps=1,
                                            dtype=options.get("dtype", "float32"))
    return scene_file, model, params, state


def load_for_scene(data_path, scene_path, *, sample_dt: Optional[float] = None,
                   angvel_frame: Optional[str] = None) -> Trajectories:
    """Read measured trajectories as the scene records them: joint coordinates if it has joints, else poses.

    Args:
        data_path: the ``.npz`` data (:mod:`jaxrb.fit.measured`, :mod:`jaxrb.fit.joint_data`).
        scene_path: the scene file the data will be fitted or scored with.
        sample_dt: sample spacing (s), for files that do not record it (joint rows never do).
        angvel_frame: ``"world"`` or ``"body"``, likewise (joint rows: ``"body"`` by default).

    Returns:
        :class:`~jaxrb.fit.measured.Trajectories`.
    """
    scene_file = load_scene(scene_path)
    model, params, _ = scene_file.build(dt=sample_dt or 0.01, substeps=1)  # for its joints' kinematics only
    if model.joints is None:
        return load_trajectories(data_path, sample_dt=sample_dt, angvel_frame=angvel_frame)
    if sample_dt is None:
        raise ValueError(f"{os.fspath(data_path)}: joint-coordinate rows do not record the sample spacing; "
                         "pass sample_dt (--sample-dt; the elbow tosses: 1/148)")
    return load_joint_trajectories(data_path, model, params, sample_dt=sample_dt,
                                   angvel_frame=angvel_frame or "body")


def check_fields(fields: Sequence[str]) -> tuple:
    """Check that a scene file can hold each field.

    Args:
        fields: a Params field name or names.

    Returns:
        The names as a tuple; a ValueError for one not in :data:`FITTABLE`.
    """
    fields = (fields,) if isinstance(fields, str) else tuple(fields)
    for name in fields:
        if name not in FITTABLE:
            raise ValueError(f"fit: field {name!r} cannot be fitted to data and written to a scene file; "
                             f"valid: {', '.join(FITTABLE)}")
    if not fields:
        raise ValueError("fit: no fields to fit")
    return fields


def rollout_losses(replay: evaluate.Replay) -> Callable:
    """Each trajectory's rollout loss as a function of Params.

    Args:
        replay: from :func:`jaxrb.fit.evaluate.prepare_replay`.

    Returns:
        ``losses(params) -> (K,)``: each trajectory's protocol position error
        (fraction of size) plus its rotation error weighed like it
        (:data:`jaxrb.fit.shooting.ROTATION_WEIGHT`: 10° counts as 10 %).
    """
    errors = evaluate.error_function(replay)

    def losses(params):
        position, rotation = errors(params)
        return position / 100.0 + shooting.ROTATION_WEIGHT * jnp.radians(rotation)

    return losses


def refine_on_rollouts(loss: Callable, theta, rounds: int = 3, width: float = 0.2,
                       say: Callable = lambda line: None) -> tuple:
    """A coordinate pattern search of ``loss(theta)`` over full rollouts: forward only, no gradient.

    Each round tries, for each coordinate in turn, the current value and
    ±width, ±width/2 away (one vmapped call of 5 rollouts of every
    trajectory), keeps the best, then divides ``width`` by 3. A cheap global
    stage on the judged objective, whose gradient is useless (chaos) but whose
    values are not.

    Args:
        loss: ``theta (P,) -> scalar``, traceable.
        theta: (P,) start.
        rounds: rounds of the search.
        width: first step, in θ's (unconstrained) units.
        say: progress lines.

    Returns:
        (theta (P,), loss there, resolution: the last round's smallest move in
        θ units, path: (θ, loss) after each round).
    """
    batch = jax.jit(jax.vmap(loss))
    theta = np.asarray(theta, np.float64)
    offsets = np.array([0.0, -1.0, -0.5, 0.5, 1.0])
    best, path, failed = None, [], 0
    for round_ in range(rounds):
        for i in range(theta.size):
            candidates = np.repeat(theta[None], offsets.size, axis=0)
            candidates[:, i] += width * offsets
            losses = np.asarray(batch(jnp.asarray(candidates, jnp.result_type(float))), np.float64)
            failed += int(np.sum(~np.isfinite(losses)))
            losses = np.where(np.isfinite(losses), losses, np.inf)
            theta, best = candidates[int(np.argmin(losses))], float(np.min(losses))
        say(f"rollout search round {round_ + 1} (step {width:.3g}): loss {best:.5g}"
            + (f"; {failed} candidates' rollouts not finite so far" if failed else ""))
        path.append((theta.copy(), best))
        resolution = 0.5 * width
        width /= 3.0
    return theta, best, resolution, path


def fit_measured(model: Model, params: Params, state: State, trajectories: Trajectories, fields, *,
                 horizons: Sequence[int] = (8, 32), stride: int = 2, starts: int = 4, spread: float = 0.5,
                 seed: int = 0, max_iterations: int = 20, tol: float = 1e-3, refine_rounds: int = 3,
                 time_budget: Optional[float] = None, progress: Optional[Callable[[str], None]] = None,
                 state_path: Optional[str] = None, scale: Optional[float] = None,
                 search_width: float = 0.2) -> DataFit:
    """Fit ``fields`` of ``params`` to ``trajectories`` (module docstring).

    Stages: ``starts`` candidate starting points costed on the first horizon,
    Levenberg–Marquardt on each horizon of ``horizons`` in turn (each from
    the last one's result: a short horizon first, where the cost is smooth,
    then a longer one, which weighs the slow effects of a parameter such as a
    slide's length), then :func:`refine_on_rollouts` on the full rollouts
    from free-flight estimates that the result is judged by.

    Args:
        model, params, state: from ``Scene.build(dt=trajectories.sample_dt / k, ...)``;
            ``params`` holds the starting values.
        trajectories: K measured trajectories of the scene's bodies.
        fields: Params field names to fit (:data:`FITTABLE`). A restitution
            that starts at 0 or 1 is fitted on the closed interval (the
            ``"clip"`` transform of :mod:`jaxrb.fit.parameter_transforms`),
            others with that module's default transforms.
        horizons: samples predicted from each measured start, one LM stage each;
            none (``()``): the rollout search alone, forward only (the elbow
            tosses, where short horizons pulled friction away from what full
            rollouts want).
        stride: samples between starts.
        starts: candidate starting points (the given one and ``starts − 1``
            drawn around it, each unconstrained coordinate ± ``spread``).
        spread: half-width of the draw, in unconstrained units (0.5: ×/÷ 1.65
            for a log-transformed field).
        seed: seed of the draw.
        max_iterations: LM iterations per horizon.
        tol: an LM stage ends when a step lowers its cost by less than this
            fraction (0.1 %: finer is below what the rollout search resolves).
        refine_rounds: rounds of the rollout search (0: none).
        time_budget: seconds for the whole fit, compile included; a stage
            that starts after it is skipped.
        progress: called with progress lines (e.g. ``print``).
        state_path: LM state file of the last horizon's stage (resumable).
        scale: the tracker's length scale; measured from free flight if None.
        search_width: the rollout search's first step (unconstrained units).

    Returns:
        :class:`DataFit`: ``params`` holds the refined values, the standard
        errors are theirs, the gradient reliability that of the last LM stage.
    """
    clock = time.perf_counter()
    say = progress or (lambda line: None)
    left = lambda: None if time_budget is None else time_budget - (time.perf_counter() - clock)  # noqa: E731
    fields = check_fields(fields)
    data, scale = calibrated(model, params, trajectories, scale)
    every = evaluate.steps_per_sample(params, trajectories)
    if model.substeps > 1:
        warnings.warn(f"fit_measured: the model has {model.substeps} substeps, unrolled in every step: its "
                      f"Jacobian compiles about 10x slower than {every * model.substeps} single steps a sample "
                      "(build with dt=sample_dt/k, substeps=1, or use build_for_data)", stacklevel=2)
    step = make_step(model)
    say(f"{trajectories.num_trajectories} trajectories; tracker length scale {scale:.4f} (from free flight)")
    # A coefficient in [0, 1] that starts at a bound (restitution 0, the default) is fitted on the
    # closed interval: the sigmoid cannot start there.
    transforms = {name: "clip" for name in fields if DEFAULT_TRANSFORMS.get(name) == "sigmoid"
                  and np.any((np.asarray(getattr(params, name)) <= 0) | (np.asarray(getattr(params, name)) >= 1))}
    theta0, unravel = ravel_pytree(to_unconstrained(params, fields, transforms))
    dtype = theta0.dtype

    def to_params(theta):
        return from_unconstrained(unravel(jnp.asarray(theta, dtype)), params, fields, transforms)

    def describe(theta):
        fitted = to_params(theta)
        return ", ".join(f"{name} {np.array2string(np.ravel(np.asarray(getattr(fitted, name))), precision=4)}"
                         for name in fields)

    theta, result, path = np.asarray(theta0, np.float64), None, []

    def record(stage, theta, cost):
        fitted = to_params(theta)
        path.append({"stage": stage, "cost": float(cost),
                     **{name: np.ravel(np.asarray(getattr(fitted, name), np.float64)) for name in fields}})

    for number, horizon in enumerate(horizons):
        if result is not None and left() is not None and left() <= 0:
            say(f"time budget spent: horizon {horizon} skipped")
            break
        segments = shooting.make_segments(state, data, horizon, stride)
        residuals_of = shooting.residual_function(step, segments, body_sizes(model), every)
        residuals = lambda t, r=residuals_of: r(to_params(t)).reshape(-1)  # noqa: E731
        say(f"horizon {horizon}: {segments.trajectory.size} segments")
        if number == 0 and starts > 1:
            draws = theta + spread * np.random.default_rng(seed).uniform(-1, 1, (starts - 1, theta.size))
            candidates = np.concatenate([theta[None], draws])
            cost = jax.jit(lambda t: 0.5 * jnp.sum(residuals(t) ** 2))
            costs = np.array([float(cost(jnp.asarray(c, dtype))) for c in candidates])
            theta = candidates[int(np.nanargmin(costs))]
            say("start costs " + ", ".join(f"{c:.5g}" for c in costs) + f"; from {describe(theta)}")
        groups = np.repeat(segments.trajectory, horizon * segments.pos.shape[2] * 6)
        last = number == len(horizons) - 1
        result = least_squares.levenberg_marquardt(
            residuals, theta, groups, max_iterations=max_iterations, tol=tol, time_budget=left(), progress=say,
            state_path=state_path if last else None, describe=describe)
        theta = result.theta
        for entry in result.history:
            record(f"horizon {horizon}", np.asarray(entry[4]), entry[1])
    if result is None and not refine_rounds:
        raise ValueError("fit_measured: no horizons and no rollout search: nothing to fit")
    covariance = None if result is None else result.covariance
    # Without a gradient stage there is no gradient to judge: NaN reliability, shown as such.
    start_gradients = np.full((1, theta.size), np.nan) if result is None else result.start_gradients
    if refine_rounds and (result is None or left() is None or left() > 0):
        replay = evaluate.prepare_replay(model, params, state, trajectories, scale=scale)
        losses = rollout_losses(replay)
        theta, _, resolution, rounds = refine_on_rollouts(lambda t: jnp.mean(losses(to_params(t))), theta,
                                                          refine_rounds, search_width, say=say)
        for point, loss in rounds:
            record("rollout search", point, loss)
        # The values now minimise the rollout loss: their uncertainty is that loss's minimum's, by a
        # bootstrap over trajectories, plus the search's own resolution (uniform, ± resolution / 2).
        say("standard errors of the rollout loss's minimum (bootstrap over trajectories)…")
        errors = least_squares.bootstrap_errors(jax.jit(jax.vmap(lambda t: losses(to_params(t)))), theta)
        covariance = np.diag(errors ** 2 + resolution ** 2 / 12.0)
    fitted = to_params(theta)
    # Standard errors of the values: the delta method through the transforms.
    values = lambda t: ravel_pytree({name: getattr(to_params(t), name) for name in fields})[0]  # noqa: E731
    slope = np.asarray(jax.jacfwd(values)(jnp.asarray(theta, dtype)), np.float64)  # (V, P)
    # Terms whose slope is 0 are left out, not 0 × inf: a coordinate the data leave undetermined (an
    # infinite bootstrap error) makes only the values that depend on it undetermined.
    outer = slope[:, :, None] * slope[:, None, :]  # (V, P, P)
    with np.errstate(invalid="ignore"):  # inf × 0 where the slope is 0: discarded by the where
        terms = np.where(outer != 0, outer * covariance[None], 0.0)
    value_errors = np.sqrt(np.maximum(terms.sum(axis=(1, 2)), 0.0))
    snr = least_squares.gradient_reliability(start_gradients @ slope.T)  # per value
    _, unravel_values = ravel_pytree({name: np.asarray(getattr(fitted, name), np.float64) for name in fields})
    return DataFit(params=fitted, fields=fields, standard_errors=unravel_values(value_errors),
                   reliability=unravel_values(snr), result=result, length_scale=scale,
                   seconds=time.perf_counter() - clock, path=path)


def fitted_scene(scene_file: SceneFile, params: Params, fields) -> dict:
    """The scene file's dict with the fitted ``fields`` written in (for ``json.dump``).

    Args:
        scene_file: the scene the fit started from.
        params: fitted Params.
        fields: the fitted field names (:data:`FITTABLE`).

    Returns:
        A ``jaxrb-scene`` dict: bodies' and planes' values and build options replaced.
    """
    data = scene_to_dict(scene_file.scene, **scene_file.build_options)
    for name in check_fields(fields):
        value = np.asarray(getattr(params, name), np.float64)
        if name == "shape_scale":
            # Sizes change, mass properties do not: they are written as the Params hold them.
            for index, (body, scale) in enumerate(zip(data["bodies"], value)):
                if body["shape"]["kind"] == "point_masses":
                    raise ValueError(f"fitted_scene: body {index}: a scaled point-mass body cannot be written "
                                     "(its points also place its centre of mass)")
                body["shape"] = {key: (np.asarray(item) * scale).tolist() if key in SHAPE_LENGTHS else item
                                 for key, item in body["shape"].items()}
                body["mass"] = float(params.mass[index])
                body["inertia"] = np.asarray(params.inertia[index], np.float64).tolist()
        elif name in BODY_FIELDS or name == "inertia":
            for body, item in zip(data["bodies"], value):
                body[name] = item.tolist()
            if name == "mass":  # a mass alone would rescale the shape's inertia: keep the inertia as fitted
                for body, item in zip(data["bodies"], np.asarray(params.inertia, np.float64)):
                    body["inertia"] = item.tolist()
        elif name in PLANE_FIELDS:
            for plane, item in zip(data["planes"], value):
                plane[PLANE_FIELDS[name]] = float(item)
        else:
            data.setdefault("build", {})[name] = float(value)
    return data
