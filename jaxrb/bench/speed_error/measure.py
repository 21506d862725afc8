"""Running, timing and scoring the configurations of the speed-against-error section.

Each configuration is scored on two axes: its **error** against the closed
form (:mod:`jaxrb.bench.speed_error.scenes`), and its **cost**: seconds of
wall time per simulated second at batch 1: the median run time (compile
excluded, ``block_until_ready``; :func:`time_jitted`) of the jitted rollout
over the scene's horizon, every state stacked, divided by the horizon. Beside
it: the compile time, and body-steps per second of ``batch`` worlds (1 024 in
the full report), ``jax.vmap`` of a ``batch_steps``-step rollout inside one
jit (final state only), with its own compile time.

One run is a :class:`Point` (:func:`run_point`, then :func:`time_batched`
for the batched figures); :func:`mark_fronts` marks the Pareto front of each
panel, :func:`batched_points` chooses which points get the batched run, and
:func:`run` does all of it for every scene of the settings.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Callable, Optional, Sequence

import jax
import jax.numpy as jnp
import numpy as np

import jaxrb as rb
from jaxrb.bench.pareto import pareto_front
from jaxrb.bench.report import fmt_sci, fmt_si
from jaxrb.bench.speed_error.grid import QUICK, build, describe
from jaxrb.bench.speed_error.scenes import SCENE_NAMES, exact_answers, trajectory_error
from jaxrb.bench.timing import compile_jitted, final_state_fn, time_compiled, time_jitted

BATCH_MODES = ("all", "pareto", "cheapest", "none")


# --- running one configuration ---------------------------------------------------------------

@dataclasses.dataclass
class Point:
    """One configuration of one scene: its error and its costs.

    Attributes:
        scene: scene name, one of :data:`SCENE_NAMES`.
        config: the configuration dict (build options).
        group: legend group (integrator/orientation, or contact model and substeps).
        label: short text beside the point (step size and anything unusual).
        panel: which plot panel and Pareto front it belongs to (the dtype for
            the tumbling scene, else ``"all"``).
        error: scalar error against the closed form (inf: failed).
        run_s: median wall seconds of the batch-1 rollout over the horizon.
        horizon: simulated seconds of that rollout.
        num_steps: steps in it.
        compile_s: compile seconds of the batch-1 rollout.
        batch: worlds of the batched run (0: not run).
        batch_steps: steps of the batched run.
        batch_run_s: median wall seconds of the batched run (nan: not run).
        batch_compile_s: its compile seconds (nan: not run).
        on_front: on the Pareto front of its panel (set after all points ran).
    """

    scene: str
    config: dict
    group: str
    label: str
    panel: str
    error: float
    run_s: float
    horizon: float
    num_steps: int
    compile_s: float
    batch: int = 0
    batch_steps: int = 0
    batch_run_s: float = math.nan
    batch_compile_s: float = math.nan
    on_front: bool = False

    @property
    def cost(self) -> float:
        """Wall seconds per simulated second at batch 1.

        Returns:
            run_s / horizon.
        """
        return self.run_s / self.horizon

    @property
    def step_us(self) -> float:
        """Wall microseconds per step at batch 1.

        Returns:
            1e6 · run_s / num_steps.
        """
        return 1e6 * self.run_s / self.num_steps

    @property
    def body_steps_per_s(self) -> float:
        """Body-steps per second of the batched run (every scene here has one body).

        Returns:
            batch · batch_steps / batch_run_s, or nan when not run.
        """
        return self.batch * self.batch_steps / self.batch_run_s if self.batch else math.nan

    def figures(self) -> list:
        """Every measured number of the point (for finiteness checks).

        Returns:
            A list of floats: error, cost, µs/step, compile s, and the batched
            run s, compile s and body-steps/s when the batched run was made.
        """
        values = [self.error, self.cost, self.step_us, self.compile_s]
        if self.batch:
            values += [self.batch_run_s, self.batch_compile_s, self.body_steps_per_s]
        return values



def _tiled_worlds(state, batch: int, seed: int = 0):
    """``batch`` copies of ``state``, each lifted by 0–1 mm and its spin nudged by ≤ 1e-3 rad/s,
    so no two worlds are the same (the physics is unchanged to that size)."""
    rng = np.random.default_rng(seed)
    tiled = jax.tree_util.tree_map(lambda a: jnp.broadcast_to(a, (batch,) + a.shape), state)
    dtype = state.pos.dtype
    lift = np.zeros((batch,) + state.pos.shape)
    lift[..., -1] = rng.uniform(0.0, 1e-3, size=(batch, state.pos.shape[0]))
    nudge = rng.uniform(-1e-3, 1e-3, size=(batch,) + state.angvel.shape)
    return tiled.replace(pos=tiled.pos + jnp.asarray(lift, dtype),
                         angvel=tiled.angvel + jnp.asarray(nudge, dtype))


def run_point(scene: str, config: dict, horizon: float, exact, repeats: int = 5) -> Point:
    """Roll one configuration out over ``horizon`` at batch 1, time it and score it.

    Args:
        scene: one of :data:`SCENE_NAMES`.
        config: a configuration dict.
        horizon: simulated seconds (rounded to whole steps).
        exact: the scene's entry of :func:`exact_answers`.
        repeats: timed calls at most (median reported).

    Returns:
        A :class:`Point` without the batched figures (see :func:`time_batched`).
    """
    model, params, state = build(scene, config)
    step = rb.make_step(model)
    num_steps = max(1, int(round(horizon / config["dt"])))

    def trajectory(state0, params0):
        return rb.rollout(step, state0, params0, num_steps)

    timing = time_jitted(trajectory, state, params, repeats=repeats, budget_s=3.0)
    error = trajectory_error(scene, timing.output, state, config["dt"], exact)
    group, label, panel = describe(scene, config)
    return Point(scene=scene, config=dict(config), group=group, label=label, panel=panel,
                 error=error, run_s=timing.run_s, horizon=num_steps * config["dt"],
                 num_steps=num_steps, compile_s=timing.compile_s)


def time_batched(result: Point, batch: int, num_steps: int, repeats: int = 5,
                 cache: Optional[dict] = None) -> Point:
    """Add body-steps/s of ``batch`` vmapped worlds to ``point`` (in place).

    Args:
        result: a :class:`Point` from :func:`run_point`.
        batch: number of worlds.
        num_steps: steps scanned inside one jit (final state only).
        repeats: timed calls at most.
        cache: optional dict of compiled functions, filled here. ``dt`` is a
            Param, so configurations that differ only in their step share one
            Model and one compiled function; its compile time is reported for
            each of them.

    Returns:
        ``result``, with batch, batch_steps, batch_run_s and batch_compile_s set.
    """
    point = result
    model, params, state = build(point.scene, point.config)
    states = _tiled_worlds(state, batch)
    key = (point.scene, model, point.config["dtype"], batch, num_steps)
    if cache is None or key not in cache:
        compiled = compile_jitted(final_state_fn(rb.make_step(model), num_steps, batched=True),
                                  states, params)
        if cache is not None:
            cache[key] = compiled
    else:
        compiled = cache[key]
    run_s, _, output = time_compiled(compiled[0], states, params, repeats=repeats, budget_s=5.0)
    if not bool(jnp.all(jnp.isfinite(output.pos))):
        raise FloatingPointError(f"speed_error: batched {point.scene} {point.label} went non-finite")
    point.batch, point.batch_steps = batch, num_steps
    point.batch_run_s, point.batch_compile_s = run_s, compiled[1]
    return point


def batched_points(points: Sequence[Point], mode: str) -> list:
    """Which points get a batched run.

    Args:
        points: (k,) list of :class:`Point`, fronts marked.
        mode: ``"all"``, ``"pareto"`` (the front of each panel), ``"cheapest"``
            (the cheapest front point of each panel) or ``"none"``.

    Returns:
        The chosen points, in order.
    """
    if mode == "all":
        return list(points)
    if mode == "none":
        return []
    chosen = []
    for panel in dict.fromkeys(p.panel for p in points):
        front = [p for p in points if p.panel == panel and p.on_front]
        chosen += front if mode == "pareto" else sorted(front, key=lambda p: p.cost)[:1]
    return chosen


def mark_fronts(points: Sequence[Point]) -> None:
    """Set ``on_front`` of every point: the Pareto front (cost, error) within its panel.

    Args:
        points: (k,) list of :class:`Point`; changed in place.
    """
    for panel in dict.fromkeys(p.panel for p in points):
        members = [p for p in points if p.panel == panel]
        front = pareto_front([p.cost for p in members], [p.error for p in members])
        for point, flag in zip(members, front):
            point.on_front = bool(flag)


# --- settings and the run ------------------------------------------------------------------

def _check_settings(settings: dict) -> dict:
    """Fill defaults from :data:`QUICK` and reject malformed settings naming the field."""
    merged = {**QUICK, **{k: v for k, v in settings.items() if k.startswith("speed_error_")}}
    for key in ("out_dir", "repeats"):
        if key in settings and f"speed_error_{key}" not in settings:
            merged[f"speed_error_{key}"] = settings[key]
    scenes = merged["speed_error_scenes"]
    for name in scenes:
        if name not in SCENE_NAMES:
            raise ValueError(f"speed_error: 'speed_error_scenes' has unknown scene {name!r}; "
                             f"valid: {', '.join(SCENE_NAMES)}")
        if not merged["speed_error_configs"].get(name):
            raise ValueError(f"speed_error: 'speed_error_configs' has no configurations for {name!r}")
        horizon = merged["speed_error_horizons"].get(name)
        if horizon is None or not horizon > 0:
            raise ValueError(f"speed_error: 'speed_error_horizons' needs a positive horizon for "
                             f"{name!r}, got {horizon!r}")
    if merged["speed_error_batch_configs"] not in BATCH_MODES:
        raise ValueError(f"speed_error: 'speed_error_batch_configs' must be one of {BATCH_MODES}, "
                         f"got {merged['speed_error_batch_configs']!r}")
    for key in ("speed_error_batch", "speed_error_batch_steps", "speed_error_repeats"):
        if not (isinstance(merged[key], int) and merged[key] >= 1):
            raise ValueError(f"speed_error: {key!r} must be an integer >= 1, got {merged[key]!r}")
    return merged


def run(settings: dict, log: Optional[Callable] = None) -> dict:
    """Run every configuration of every scene in ``settings``.

    Args:
        settings: keys ``speed_error_*`` as in :data:`QUICK` (missing ones
            are taken from it); ``repeats`` is used when
            ``speed_error_repeats`` is absent.
        log: optional progress callback taking one string.

    Returns:
        {scene: list of :class:`Point`}, fronts marked, in configuration order.
    """
    if not jax.config.jax_enable_x64:
        raise RuntimeError("speed_error: needs jax_enable_x64 (the float64 tumbling runs)")
    settings = _check_settings(settings)
    log = log or (lambda text: None)
    exact = exact_answers(settings["speed_error_horizons"]["tumble"])
    repeats = settings["speed_error_repeats"]
    results = {}
    cache = {}
    for scene in settings["speed_error_scenes"]:
        horizon = settings["speed_error_horizons"][scene]
        points = []
        for config in settings["speed_error_configs"][scene]:
            point = run_point(scene, config, horizon, exact[scene], repeats)
            log(f"speed/error {scene:>6} {point.group:>22} {point.label:>16} {point.panel:>7}: "
                f"error {fmt_sci(point.error)}, {fmt_sci(point.cost)} s/s, compile "
                f"{point.compile_s:.2f} s")
            points.append(point)
        mark_fronts(points)
        for point in batched_points(points, settings["speed_error_batch_configs"]):
            time_batched(point, settings["speed_error_batch"], settings["speed_error_batch_steps"],
                         repeats, cache)
            log(f"speed/error {scene:>6} {point.group:>22} {point.label:>16} {point.panel:>7}: "
                f"batch {point.batch}: {fmt_si(point.body_steps_per_s, ' body-steps/s')}, "
                f"compile {point.batch_compile_s:.2f} s")
        results[scene] = points
    return results
