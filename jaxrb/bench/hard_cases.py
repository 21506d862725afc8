"""Hard-case stability suite: pass/fail checks on scenes that break weak solvers.

Every case is a function ``case(*, out_dir=None, log=None, **settings) ->
CaseResult``; keyword settings override the case's defaults (``DEFAULTS``), so
the tests can run small versions (fewer boxes, shorter time) and deliberately
broken ones (soft contact, no contact, an integrator that gains energy). All
cases use impulse contact (where there is contact) at dt = 1/60 s in float64
unless told otherwise. ``build`` settings go to ``Scene.build`` on top of the
case's own.

The cases (issue 6, item 3):

1. **tallest_stack**: columns of 0.2 m cubes (1 kg, μ = 0.5) of increasing
   height, each simulated 10 s; the search stops at the first height that does
   not stand. Passes when the tallest standing column has at least
   ``required`` boxes (10, the issue's 10-box stack target).
2. **pyramid_2d**: a 2D pyramid of 20 rows (210 boxes, 5 % gaps, the contact
   benchmark's scene) standing 10 s.
3. **mass_ratio**: a 3D column light–heavy–light (1 kg, r kg, 1 kg from the
   ground up) for r = 100 and 1 000: the heavy box sits on a light one and a
   light one sits on it, the two hard pairings at once. Each ratio runs at
   dt = 1/60 s with 8, 16, then 32 substeps until one stands (measured in
   float64: 1:100 stands with 8; 1:1000 sinks 22 mm into the light box with
   8 and 5.7 mm with 16, and stands with 32, penetration 1.25 mm).
4. **impact**: a sphere (r = 0.1 m) and a box (half 0.1 m), 1 kg each,
   thrown down at 10, 30, 100, 300, 1 000 m/s from 0.9 m above a plane, with and
   without ``time_of_impact``; a body "holds" when it ends (after 1 s) with
   its centre above the plane (the brief's "does not tunnel"), and "rests"
   when that centre is within 1 cm of 0.1 m (no rebound: e = 0); both
   thresholds (the fastest speed with every slower one holding / resting)
   are reported. Passes when the sphere with time of impact holds at every
   speed and the box (discrete contact) holds at 10 m/s. Measured: nothing
   tunnels up to 1 000 m/s, but the box hit at 1 000 m/s is thrown back up
   (3.2 m above the plane after 1 s), so it does not rest.
5. **spin**: a free body, principal inertia (0.3, 0.35, 0.4) kg m², spinning
   at 100 rad/s about its intermediate axis (ω₀ = (0.1, 100, 0.1) rad/s, the
   small components seed the flip), 10 s at dt = 1/60 s (1.7 rad per step).
   Passes when ``implicit_gyro`` gains no energy: max E(t)/E₀ − 1 ≤ 1e-6 (a
   rounding allowance; a gaining integrator goes far beyond). The other
   integrators are reported beside it.
6. **overlap_recovery**: a 2D pyramid of 10 rows started with every box
   overlapping each neighbour (and the bottom row the ground) by 25 % of its
   side. Passes when the overlaps are resolved (deepest contact < 1 mm after
   5 s) and the kinetic energy stays bounded: max KE ≤ Σᵢ ½·mᵢ·((rᵢ+1)·v_push)²,
   rᵢ the box's row (0 at the ground) and v_push = 3 m/s the default
   ``max_push_velocity``. The soft step pushes each overlapping pair apart at
   most at v_push, and the relax passes keep a separating velocity (they only
   stop approach), so a box on r overlapping joints can leave at up to
   (r+1)·v_push: the bound is every box doing so at once. The report also
   gives ½·M·v_push² (every box at the cap, no chaining) for scale. Rigid
   Baumgarte correction (no relax passes, no cap, damping ratio 0) goes
   beyond the bound; dropping only the cap and the relax passes doubles the
   KE of a 6-box pyramid (16.5 → 33.6 J) but stays inside its 90 J bound,
   because the soft constraint itself limits the push-out speed.
7. **long_rest**: 10⁵ steps (dt = 1/60 s, 28 simulated minutes) of a resting
   3-box column (the mass-ratio case's Model, so no extra compile; a 3-box
   column at 8 substeps costs about 1–2 ms per step on one core, so 10⁵ steps
   of a taller one would dominate the whole report), run in chunks of
   ``lax.scan``; passes when nothing is NaN and no body moves more than 1 cm
   (3D displacement) from its start.

"Stands" (cases 1–3) is the issue-3 criterion of ``tests/test_stacks.py``:
the top box drifts < 1 cm horizontally, the deepest contact penetration
stays < 5 mm, every body moves < 1 cm/s in the last second, and the top box
ends within 2 cm of its start height (no collapse). Penetration is per
contact, not the top box's total sink: a column of n soft joints sinks n
times one joint, so a bound on the top box's height would measure the
column's length, not the contact's stiffness.

Compiled rollouts are cached per Model (:func:`_chunk_runner`): cases with
the same Model share one compile (a 3-box column in the stack search, the
mass-ratio column and the long rest; the 2D pyramids of the same size), and
a compile reported as 0 s was a cache hit.
"""

from __future__ import annotations

import dataclasses
import math
import os
import time
from typing import Callable, Optional

import jax
import jax.numpy as jnp
import numpy as np

import jaxrb as rb
from jaxrb.bench.contact import column_scene, pyramid2d_scene
from jaxrb.bench.report import fmt_fixed, fmt_sci, fmt_step, markdown_table
from jaxrb.compile import jit
from jaxrb.options import grouped

HALF = 0.1  # half side of every box (m)
BOX_MASS = 1.0
FRICTION = 0.5
DT = 1.0 / 60.0

# Issue-3 "stands" criteria (tests/test_stacks.py).
DRIFT_TOL = 0.01  # m, top box horizontal drift
PENETRATION_TOL = 0.005  # m, deepest contact
SPEED_TOL = 0.01  # m/s, every body in the last second
COLLAPSE_TOL = 0.02  # m, top box height change at the end
REST_TOL = 0.01  # m, impact: |final centre height − 0.1 m| of a body that came to rest
STANDS_TEXT = (f"top drift < {DRIFT_TOL * 100:g} cm, penetration < {PENETRATION_TOL * 1000:g} mm, "
               f"speed in last 1 s < {SPEED_TOL * 100:g} cm/s, top within {COLLAPSE_TOL * 100:g} cm of start")

#: Default settings of every case (FULL mode). ``build`` goes to Scene.build.
DEFAULTS = {
    "tallest_stack": dict(heights=(5, 10, 15, 20, 30), required=10, seconds=10.0,
                          build=dict(dt=DT, substeps=8), every=6, chunk_steps=60),
    "pyramid_2d": dict(rows=20, seconds=10.0, build=dict(dt=DT, substeps=8), every=1, chunk_steps=60),
    "mass_ratio": dict(ratios=(100.0, 1000.0), substeps=(8, 16, 32), seconds=10.0, build=dict(dt=DT),
                       every=6, chunk_steps=60),
    "impact": dict(speeds=(10.0, 30.0, 100.0, 300.0, 1000.0), time_of_impact=(False, True), seconds=1.0,
                   gap=0.9, build=dict(dt=DT, substeps=4), required_box_speed=10.0),
    "spin": dict(omega=100.0, seconds=10.0, dt=DT, integrator="implicit_gyro",
                 others=("semi_implicit", "rk4", "rk4_body", "euler"), tolerance=1e-6, every=1, chunk_steps=60),
    "overlap_recovery": dict(rows=10, overlap=0.25, seconds=5.0, build=dict(dt=DT, substeps=8),
                             push_speed=3.0, overlap_tol=1e-3, every=1, chunk_steps=60),
    "long_rest": dict(count=3, num_steps=100_000, build=dict(dt=DT, substeps=8), drift_tol=0.01,
                      every=6, chunk_steps=60),
}

CASES = tuple(DEFAULTS)

#: FULL: the issue's sizes. QUICK: small versions, well under a minute of
#: compute on two cores once compiled (3-box column shared by three cases).
FULL = {name: {} for name in CASES}
QUICK = {
    "tallest_stack": dict(heights=(3,), required=3, seconds=3.0),
    "pyramid_2d": dict(rows=4, seconds=3.0),
    "mass_ratio": dict(ratios=(100.0,), substeps=(8,), seconds=3.0),
    "impact": dict(speeds=(10.0, 100.0, 300.0)),
    "spin": dict(seconds=3.0, others=("semi_implicit", "euler")),
    "overlap_recovery": dict(rows=4, seconds=3.0),
    "long_rest": dict(count=3, num_steps=600),
}


@dataclasses.dataclass
class CaseResult:
    """Outcome of one hard case.

    Attributes:
        name: the case's name (a key of ``DEFAULTS``).
        passed: whether the criterion held.
        measured: figure name -> value (SI units, named in the key, e.g.
            ``drift_m``); every value finite unless the simulation blew up.
        measured_text: the figures as a short human-readable line.
        criterion: the pass condition in words.
        settings: the settings the case ran with (defaults merged with overrides).
        wall_s: wall seconds of the whole case (compiles included).
        compile_s: seconds spent compiling (0 where every compile was a cache hit).
        figure: path of the PNG written, or ``None``.
        rows: per-configuration details (one dict per height, ratio, speed...).
    """

    name: str
    passed: bool
    measured: dict
    measured_text: str
    criterion: str
    settings: dict
    wall_s: float
    compile_s: float
    figure: Optional[str] = None
    rows: list = dataclasses.field(default_factory=list)


def _settings(name: str, overrides: dict) -> dict:
    """Defaults of case ``name`` with ``overrides``; ``build`` dicts are merged, unknown keys rejected."""
    defaults = DEFAULTS[name]
    unknown = set(overrides) - set(defaults)
    if unknown:
        raise ValueError(f"hard case {name!r}: unknown setting(s) {sorted(unknown)}; "
                         f"valid: {sorted(defaults)}")
    merged = {**defaults, **overrides}
    if "build" in defaults:
        merged["build"] = {**defaults["build"], **overrides.get("build", {})}
    return merged


# --- compiled rollouts in chunks, cached per Model ---------------------------------

_RUNNERS: dict = {}


def _summary(model, params, state):
    """What a case keeps of one saved state: pose, velocity, total KE, deepest penetration."""
    kinetic = jnp.sum(rb.kinetic_energy(model, params, state))
    if model.contact != "none" and model.num_contacts:
        contacts = rb.detect_contacts(model, params, state)
        penetration = jnp.max(jnp.where(contacts.active, -contacts.dist, 0.0))
    else:
        penetration = jnp.zeros((), state.pos.dtype)
    return dict(pos=state.pos, vel=state.vel, kinetic=kinetic, penetration=penetration)


def _chunk_runner(model, state, params, every: int, samples: int, batched: bool = False):
    """Compiled ``chunk(state, params) -> (state, summaries)`` of ``every * samples`` steps.

    Cached on (model, every, samples, batched, dtype and shapes), so cases with
    the same Model share the compile. Returns ``(compiled, compile_s)``;
    ``compile_s`` is 0 on a cache hit.
    """
    shapes = tuple((leaf.shape, str(leaf.dtype)) for leaf in jax.tree_util.tree_leaves((state, params)))
    key = (model, every, samples, batched, shapes)
    if key in _RUNNERS:
        return _RUNNERS[key], 0.0
    step = rb.make_step(model)

    def chunk(current, params_):
        def advance(inner, _):
            inner = jax.lax.scan(lambda s, __: (step(s, params_), None), inner, None, length=every)[0]
            return inner, _summary(model, params_, inner)

        return jax.lax.scan(advance, current, None, length=samples)

    if batched:
        chunk = jax.vmap(chunk, in_axes=(0, None))
    start = time.perf_counter()
    compiled = jit(chunk).lower(state, params).compile()
    _RUNNERS[key] = compiled
    return compiled, time.perf_counter() - start


@dataclasses.dataclass
class Trace:
    """Saved summaries of a simulation (leading axis: saved samples; batch next when batched).

    Attributes:
        times: (T,) simulated seconds of the samples.
        pos: (T, [B,] n, dim) centre-of-mass positions.
        vel: (T, [B,] n, dim) velocities.
        kinetic: (T, [B]) total kinetic energy (J).
        penetration: (T, [B]) deepest contact penetration (m), 0 without contact.
        steps: steps simulated (a multiple of the chunk length).
        finite: False when a chunk produced a non-finite value (simulation stopped there).
        compile_s, run_s: compile seconds (0 on a cache hit) and wall seconds of the runs.
    """

    times: np.ndarray
    pos: np.ndarray
    vel: np.ndarray
    kinetic: np.ndarray
    penetration: np.ndarray
    steps: int
    finite: bool
    compile_s: float
    run_s: float


def simulate(model, params, state, num_steps: int, every: int, chunk_steps: int, batched: bool = False,
             reduce: Optional[Callable] = None) -> Trace:
    """Run ``num_steps`` steps (rounded up to whole chunks) and keep every ``every``-th state's summary.

    Args:
        model, params, state: from ``Scene.build`` (state with a leading batch
            axis when ``batched``: pos (B, n, dim), ...).
        num_steps: steps to run, rounded up to a multiple of ``chunk_steps``.
        every: steps between saved summaries; must divide ``chunk_steps``.
        chunk_steps: steps per compiled ``lax.scan`` call; the host checks
            each chunk for NaN/inf and stops at the first bad one.
        batched: vmap the chunk over the leading axis of ``state``.
        reduce: optional ``f(chunk_summaries: dict of np arrays) -> dict`` applied
            to each chunk on the host; only its output is kept (for long runs).

    Returns:
        A :class:`Trace`; with ``reduce``, its array fields hold the stacked
        outputs of ``reduce`` (one entry per chunk) under the same names.
    """
    if every < 1 or chunk_steps % every:
        raise ValueError(f"simulate: 'every' ({every}) must divide 'chunk_steps' ({chunk_steps})")
    compiled, compile_s = _chunk_runner(model, state, params, every, chunk_steps // every, batched)
    chunks = max(1, math.ceil(num_steps / chunk_steps))
    dt = float(params.dt)
    kept, finite, start = [], True, time.perf_counter()
    done = 0
    for _ in range(chunks):
        state, summary = compiled(state, params)
        summary = {k: np.asarray(v) for k, v in jax.block_until_ready(summary).items()}
        if batched:  # vmap put the batch axis first; keep time first like the unbatched trace
            summary = {k: np.swapaxes(v, 0, 1) for k, v in summary.items()}
        done += 1
        kept.append(reduce(summary) if reduce is not None else summary)
        if not all(np.all(np.isfinite(v)) for v in summary.values()):
            finite = False
            break
    run_s = time.perf_counter() - start
    stacked = {k: (np.stack if reduce is not None else np.concatenate)([c[k] for c in kept]) for k in kept[0]}
    if reduce is None:
        times = dt * every * np.arange(1, len(stacked["kinetic"]) + 1)
    else:
        times = dt * chunk_steps * np.arange(1, done + 1)
    return Trace(times=times, pos=stacked.get("pos"), vel=stacked.get("vel"),
                 kinetic=stacked.get("kinetic"), penetration=stacked.get("penetration"),
                 steps=done * chunk_steps, finite=finite, compile_s=compile_s, run_s=run_s)


# --- scenes ----------------------------------------------------------------------------

def overlapped_pyramid_scene(rows: int, overlap: float):
    """2D pyramid whose boxes overlap each neighbour and the ground by ``overlap`` of their side.

    Args:
        rows: rows of the pyramid (rows·(rows+1)/2 boxes).
        overlap: overlap as a fraction of the side (0.25: 5 cm of a 0.2 m box).

    Returns:
        The Scene (body order: row by row from the ground, left to right).
    """
    if not 0.0 <= overlap < 1.0:
        raise ValueError(f"overlapped_pyramid_scene: 'overlap' must be in [0, 1), got {overlap!r}")
    side = 2 * HALF
    pitch = side * (1.0 - overlap)
    scene = rb.Scene(dim=2)
    scene.add_plane(friction=FRICTION)
    for row in range(rows):
        for column in range(rows - row):
            x = (column - (rows - 1 - row) / 2.0) * pitch
            scene.add_body(rb.Box((HALF, HALF)), mass=BOX_MASS, pos=(x, HALF - overlap * side + pitch * row),
                           friction=FRICTION)
    return scene


# --- checks --------------------------------------------------------------------------

def standing_figures(trace: Trace, state0, top: int, dt: float) -> dict:
    """The issue-3 figures of a stack run: top drift, penetration, last-second speed, top drop.

    Args:
        trace: an unbatched, unreduced :class:`Trace`.
        state0: the initial State (pos (n, dim)).
        top: index of the top body.
        dt: the time step (s), to find the samples of the last second.

    Returns:
        dict with ``drift_m``, ``penetration_m``, ``last_speed_mps``, ``top_drop_m``
        (inf where the run went non-finite) and ``finite``.
    """
    start = np.asarray(state0.pos)[top]
    horizontal = trace.pos[:, top, :-1] - start[:-1]
    drift = float(np.max(np.linalg.norm(horizontal, axis=-1)))
    penetration = float(np.max(trace.penetration))
    last = trace.times > trace.times[-1] - 1.0 + 0.5 * dt
    speed = float(np.max(np.linalg.norm(trace.vel[last], axis=-1)))
    drop = float(abs(trace.pos[-1, top, -1] - start[-1]))
    figures = dict(drift_m=drift, penetration_m=penetration, last_speed_mps=speed, top_drop_m=drop)
    if not trace.finite:
        figures = {k: math.inf for k in figures}
    figures["finite"] = trace.finite
    return figures


def stands(figures: dict) -> bool:
    """Whether :func:`standing_figures` meet the issue-3 criteria (strict; NaN fails)."""
    return bool(figures["finite"] and figures["drift_m"] < DRIFT_TOL
                and figures["penetration_m"] < PENETRATION_TOL
                and figures["last_speed_mps"] < SPEED_TOL and figures["top_drop_m"] < COLLAPSE_TOL)


def _standing_text(figures: dict) -> str:
    if not figures["finite"]:
        return "non-finite state"
    return (f"drift {figures['drift_m'] * 1000:.2f} mm, pen {figures['penetration_m'] * 1000:.2f} mm, "
            f"v_last {figures['last_speed_mps'] * 100:.3f} cm/s, drop {figures['top_drop_m'] * 1000:.2f} mm")


def _steps(seconds: float, dt: float) -> int:
    return max(1, int(round(seconds / dt)))


# --- figures -------------------------------------------------------------------------

def _save_figure(out_dir: Optional[str], filename: str, draw: Callable, panels: int = 1) -> Optional[str]:
    """Draw with ``draw(axes)`` on a fresh Figure (no pyplot state) and save PNG; None without out_dir."""
    if out_dir is None:
        return None
    from matplotlib.figure import Figure

    os.makedirs(out_dir, exist_ok=True)
    figure = Figure(figsize=(5.0 * panels, 3.6))
    axes = figure.subplots(1, panels, squeeze=False)[0]
    draw(axes)
    for axis in axes:
        axis.grid(True, alpha=0.3)
    figure.tight_layout()
    path = os.path.join(out_dir, filename)
    figure.savefig(path, dpi=100)
    return path


def _draw_standing(axes, series, tolerance_lines=True):
    """series: list of (label, times, drift_m, penetration_m)."""
    for label, times, drift, penetration in series:
        axes[0].plot(times, 1000 * drift, label=label)
        axes[1].plot(times, 1000 * penetration, label=label)
    axes[0].set_ylabel("top box horizontal drift (mm)")
    axes[1].set_ylabel("deepest penetration (mm)")
    if tolerance_lines:
        axes[0].axhline(1000 * DRIFT_TOL, color="k", ls=":", lw=1)
        axes[1].axhline(1000 * PENETRATION_TOL, color="k", ls=":", lw=1)
    for axis in axes:
        axis.set_xlabel("t (s)")
        axis.set_yscale("symlog", linthresh=0.1)
        axis.legend(fontsize=7)


def _drift_series(trace: Trace, state0, top: int):
    drift = np.linalg.norm(trace.pos[:, top, :-1] - np.asarray(state0.pos)[top, :-1], axis=-1)
    return drift, trace.penetration


def _log(log, text):
    if log is not None:
        log(text)


# --- the cases -----------------------------------------------------------------------

def tallest_stack(*, out_dir: Optional[str] = None, log=None, **overrides) -> CaseResult:
    """Case 1: tallest 3D column of boxes that stands, searched upward over ``heights``.

    Args:
        out_dir: folder for ``hard_tallest_stack.png`` (none written when ``None``).
        log: optional ``f(str)`` for progress lines.
        **overrides: ``heights`` (increasing box counts), ``required`` (boxes the
            tallest standing column must reach to pass), ``seconds``, ``build``
            (Scene.build settings), ``every``, ``chunk_steps``.

    Returns:
        A :class:`CaseResult`; ``measured['tallest']`` is 0 when even the first height falls.
    """
    settings = _settings("tallest_stack", overrides)
    wall = time.perf_counter()
    rows, series, compile_s, tallest = [], [], 0.0, 0
    for height in settings["heights"]:
        model, params, state = column_scene([BOX_MASS] * height).build(**grouped(settings["build"]))
        trace = simulate(model, params, state, _steps(settings["seconds"], float(params.dt)),
                         settings["every"], settings["chunk_steps"])
        compile_s += trace.compile_s
        figures = standing_figures(trace, state, height - 1, float(params.dt))
        ok = stands(figures)
        rows.append(dict(height=height, stands=ok, run_s=trace.run_s, **figures))
        series.append((f"{height} boxes", trace.times, *_drift_series(trace, state, height - 1)))
        _log(log, f"hard tallest_stack {height:>3} boxes: {'stands' if ok else 'FALLS'} "
                  f"({_standing_text(figures)}), compile {trace.compile_s:.1f} s, run {trace.run_s:.1f} s")
        if not ok:
            break
        tallest = height
    first_failure = next((r for r in rows if not r["stands"]), None)
    text = f"tallest standing: {tallest} boxes" + (
        f"; {first_failure['height']} falls ({_standing_text(first_failure)})" if first_failure
        else f" (tallest tried; {_standing_text(rows[-1])})")
    figure = _save_figure(out_dir, "hard_tallest_stack.png", lambda axes: _draw_standing(axes, series), 2)
    return CaseResult(
        name="tallest_stack", passed=tallest >= settings["required"],
        measured=dict(tallest=tallest, tried=[r["height"] for r in rows]), measured_text=text,
        criterion=f"tallest 3D column standing {settings['seconds']:g} s ≥ {settings['required']} boxes "
                  f"(stands: {STANDS_TEXT})",
        settings=settings, wall_s=time.perf_counter() - wall, compile_s=compile_s, figure=figure, rows=rows)


def pyramid_2d(*, out_dir: Optional[str] = None, log=None, **overrides) -> CaseResult:
    """Case 2: a 2D pyramid of ``rows`` rows (rows·(rows+1)/2 boxes, 5 % gaps) standing.

    Args:
        out_dir: folder for ``hard_pyramid_2d.png``.
        log: optional ``f(str)`` for progress lines.
        **overrides: ``rows``, ``seconds``, ``build``, ``every``, ``chunk_steps``.

    Returns:
        A :class:`CaseResult` with the standing figures of the top box.
    """
    settings = _settings("pyramid_2d", overrides)
    wall = time.perf_counter()
    model, params, state = pyramid2d_scene(settings["rows"]).build(**grouped(settings["build"]))
    top = model.num_bodies - 1
    trace = simulate(model, params, state, _steps(settings["seconds"], float(params.dt)),
                     settings["every"], settings["chunk_steps"])
    figures = standing_figures(trace, state, top, float(params.dt))
    ok = stands(figures)
    _log(log, f"hard pyramid_2d {settings['rows']} rows ({model.num_bodies} boxes): "
              f"{'stands' if ok else 'FALLS'} ({_standing_text(figures)}), compile {trace.compile_s:.1f} s, "
              f"run {trace.run_s:.1f} s")
    series = [(f"{settings['rows']} rows", trace.times, *_drift_series(trace, state, top))]
    figure = _save_figure(out_dir, "hard_pyramid_2d.png", lambda axes: _draw_standing(axes, series), 2)
    return CaseResult(
        name="pyramid_2d", passed=ok, measured={k: v for k, v in figures.items()},
        measured_text=_standing_text(figures),
        criterion=f"{model.num_bodies}-box 2D pyramid stands {settings['seconds']:g} s ({STANDS_TEXT})",
        settings=settings, wall_s=time.perf_counter() - wall, compile_s=trace.compile_s, figure=figure,
        rows=[dict(rows=settings["rows"], boxes=model.num_bodies, run_s=trace.run_s, **figures)])


def mass_ratio(*, out_dir: Optional[str] = None, log=None, **overrides) -> CaseResult:
    """Case 3: light–heavy–light 3D columns (1 kg, r kg, 1 kg from the ground up) standing.

    The soft contact's spring acts on the pair's effective mass, about the
    light box's, so the heavy box sinks into the light one by about
    r·g/ω², and ω grows with the substeps (the default stiffness is a
    quarter of the substep rate). Each ratio is therefore run with the
    entries of ``substeps`` in turn, at the same dt, until one stands; the
    report gives the fewest that stood.

    Args:
        out_dir: folder for ``hard_mass_ratio.png``.
        log: optional ``f(str)`` for progress lines.
        **overrides: ``ratios`` (heavy mass / light mass), ``substeps`` (counts
            to try, ascending), ``seconds``, ``build``, ``every``, ``chunk_steps``.

    Returns:
        A :class:`CaseResult`; passes when every ratio stands with one of the
        substep counts.
    """
    settings = _settings("mass_ratio", overrides)
    if "substeps" in settings["build"]:
        raise ValueError("hard case 'mass_ratio': give the substep counts to try as the 'substeps' "
                         "setting, not in 'build'")
    wall = time.perf_counter()
    rows, series, compile_s = [], [], 0.0
    for ratio in settings["ratios"]:
        for substeps in settings["substeps"]:
            build = {**settings["build"], "substeps": substeps}
            model, params, state = column_scene([BOX_MASS, BOX_MASS * ratio, BOX_MASS]).build(**grouped(build))
            trace = simulate(model, params, state, _steps(settings["seconds"], float(params.dt)),
                             settings["every"], settings["chunk_steps"])
            compile_s += trace.compile_s
            figures = standing_figures(trace, state, 2, float(params.dt))
            ok = stands(figures)
            _log(log, f"hard mass_ratio 1:{ratio:g}, {substeps} substeps: {'stands' if ok else 'FALLS'} "
                      f"({_standing_text(figures)}), compile {trace.compile_s:.1f} s, run {trace.run_s:.1f} s")
            if ok:
                break
        rows.append(dict(ratio=ratio, stands=ok, substeps=substeps, run_s=trace.run_s, **figures))
        series.append((f"1:{ratio:g}, {substeps} substeps", trace.times, *_drift_series(trace, state, 2)))
    text = "; ".join(f"1:{r['ratio']:g} {'stands' if r['stands'] else 'FALLS'} at {r['substeps']} substeps "
                     f"({_standing_text(r)})" for r in rows)
    figure = _save_figure(out_dir, "hard_mass_ratio.png", lambda axes: _draw_standing(axes, series), 2)
    return CaseResult(
        name="mass_ratio", passed=all(r["stands"] for r in rows),
        measured={f"1:{r['ratio']:g} penetration_m": r["penetration_m"] for r in rows}, measured_text=text,
        criterion=f"light–heavy–light column (1, r, 1 kg) stands {settings['seconds']:g} s for r ∈ "
                  f"{{{', '.join(f'{r:g}' for r in settings['ratios'])}}} at dt = "
                  f"{fmt_step(settings['build']['dt'])} s with one of "
                  f"{', '.join(str(n) for n in settings['substeps'])} substeps ({STANDS_TEXT})",
        settings=settings, wall_s=time.perf_counter() - wall, compile_s=compile_s, figure=figure, rows=rows)


def impact_scene():
    """A sphere (r = 0.1) and a box (half 0.1), 1 kg, e = 0, over a plane; they touch only the plane."""
    scene = rb.Scene(dim=3)
    scene.add_plane(friction=FRICTION)
    # Categories 2 and 4 with mask 1: each meets the plane (category 1) but not the other.
    scene.add_body(rb.Sphere(HALF), mass=BOX_MASS, pos=(-1.0, 0.0, 1.0), friction=FRICTION,
                   collision_category=2, collision_mask=1, name="sphere")
    scene.add_body(rb.Box((HALF,) * 3), mass=BOX_MASS, pos=(1.0, 0.0, 1.0), friction=FRICTION,
                   collision_category=4, collision_mask=1, name="box")
    return scene


def _fastest_passing(speeds, passed) -> float:
    """The largest speed whose run and every slower run passed (0 if the slowest failed)."""
    fastest = 0.0
    for speed, ok in zip(speeds, passed):
        if not ok:
            break
        fastest = float(speed)
    return fastest


def impact(*, out_dir: Optional[str] = None, log=None, **overrides) -> CaseResult:
    """Case 4: the fastest downward impact on a plane that does not tunnel.

    Both bodies start with the lowest point ``gap`` above the plane and speed v
    straight down; a body holds when its centre ends above the plane after
    ``seconds``. Each speed is a one-world run of the same compiled rollout
    (one compile per setting of ``time_of_impact``): ``vmap`` over the speeds
    compiled more than twice as long (12.2 against 5.8 s without time of
    impact, 20.1 against 8.9 s with it) to save milliseconds of running.

    Args:
        out_dir: folder for ``hard_impact.png``.
        log: optional ``f(str)`` for progress lines.
        **overrides: ``speeds`` (m/s, increasing), ``time_of_impact`` (tuple of
            bools to try), ``seconds``, ``gap`` (m), ``build``,
            ``required_box_speed`` (m/s the box must hold at without time of impact).

    Returns:
        A :class:`CaseResult`; ``measured`` holds the fastest holding speed per
        body and option (0 when none holds).
    """
    settings = _settings("impact", overrides)
    wall = time.perf_counter()
    speeds = np.asarray(settings["speeds"], dtype=np.float64)
    rows, compile_s, fastest, resting, curves = [], 0.0, {}, {}, {}
    for toi in settings["time_of_impact"]:
        model, params, state = impact_scene().build(**grouped(dict(settings["build"], time_of_impact=bool(toi))))
        dtype = state.pos.dtype
        num_steps = _steps(settings["seconds"], float(params.dt))
        pos = np.asarray(state.pos).copy()
        pos[:, 2] = HALF + settings["gap"]
        state = state.replace(pos=jnp.asarray(pos, dtype))
        traces = []
        for speed in speeds:
            vel = np.zeros(state.vel.shape)
            vel[:, 2] = -speed
            thrown = state.replace(vel=jnp.asarray(vel, dtype))
            traces.append(simulate(model, params, thrown, num_steps, 1, num_steps))
            compile_s += traces[-1].compile_s
        times = traces[0].times
        heights = np.stack([trace.pos[:, :, 2] for trace in traces], axis=1)  # (T, speeds, bodies)
        final_z = heights[-1]  # (speeds, bodies)
        for body, name in enumerate(("sphere", "box")):
            holds = np.isfinite(final_z[:, body]) & (final_z[:, body] > 0.0)
            holding = [float(v) for v, ok in zip(speeds, holds) if ok]
            # Fastest speed with every slower one holding too (the tunnelling threshold).
            fastest[(name, bool(toi))] = _fastest_passing(speeds, holds)
            # Stricter: every speed up to v also comes to rest on the plane (e = 0, no rebound).
            rests = np.isfinite(final_z[:, body]) & (np.abs(final_z[:, body] - HALF) < REST_TOL)
            resting[(name, bool(toi))] = _fastest_passing(speeds, rests)
            curves[(name, bool(toi))] = (times, heights[:, :, body])
            for v, ok, z in zip(speeds, holds, final_z[:, body]):
                rows.append(dict(body=name, time_of_impact=bool(toi), speed=float(v), holds=bool(ok),
                                 final_z=float(z), rests=bool(abs(z - HALF) < REST_TOL)))
            _log(log, f"hard impact {name:>6} toi={str(bool(toi)):<5}: holds at {holding} m/s, "
                      f"fastest before the first tunnel {fastest[(name, bool(toi))]:g} m/s "
                      f"(compile {traces[0].compile_s:.1f} s)")
    sphere_ok = (("sphere", True) not in fastest) or fastest[("sphere", True)] >= float(speeds.max())
    box_key = ("box", False) if ("box", False) in fastest else ("box", True)
    passed = sphere_ok and fastest[box_key] >= settings["required_box_speed"]
    text = "; ".join(f"{name}{' +TOI' if toi else ''}: {v:g} m/s (rests up to {resting[(name, toi)]:g})"
                     for (name, toi), v in fastest.items())

    def draw(axes):
        for axis, toi in zip(axes, settings["time_of_impact"]):
            for name, style in (("sphere", "-"), ("box", "--")):
                times, z = curves[(name, bool(toi))]
                for index, v in enumerate(speeds):
                    axis.plot(times, np.clip(z[:, index], -1.0, None), style, color=f"C{index}",
                              label=f"{name} {v:g} m/s")
            axis.axhline(0.0, color="k", lw=1)
            axis.set_title(f"time_of_impact={bool(toi)}", fontsize=9)
            axis.set_xlabel("t (s)")
            axis.set_ylabel("centre height z (m), clipped at −1")
            axis.legend(fontsize=6, ncol=2)

    figure = _save_figure(out_dir, "hard_impact.png", draw, len(settings["time_of_impact"]))
    return CaseResult(
        name="impact", passed=bool(passed),
        measured={**{f"{name}{'_toi' if toi else ''}_fastest_mps": v for (name, toi), v in fastest.items()},
                  **{f"{name}{'_toi' if toi else ''}_resting_mps": v for (name, toi), v in resting.items()}},
        measured_text="fastest speed with no tunnel: " + text,
        criterion=(f"sphere with time_of_impact holds at every speed up to {speeds.max():g} m/s and the box "
                   f"(discrete contact) holds at ≥ {settings['required_box_speed']:g} m/s "
                   f"(holds: centre above the plane after {settings['seconds']:g} s; "
                   f"dt {fmt_step(settings['build']['dt'])} s, {settings['build']['substeps']} substeps)"),
        settings=settings, wall_s=time.perf_counter() - wall, compile_s=compile_s, figure=figure, rows=rows)


SPIN_INERTIA = (0.3, 0.35, 0.4)


def spin_energy(integrator: str, omega: float, seconds: float, dt: float, every: int = 1,
                chunk_steps: int = 60):
    """Relative energy history E(t)/E₀ − 1 of the body spinning about its intermediate axis.

    Args:
        integrator: one of ``rb`` integrators (``"implicit_gyro"``, ...).
        omega: spin rate about the intermediate (y) axis, rad/s.
        seconds: simulated time.
        dt: time step (s).
        every, chunk_steps: sampling and chunking of :func:`simulate`.

    Returns:
        ``(times (T,), relative_change (T,), trace)``.
    """
    scene = rb.Scene(dim=3, gravity=(0.0, 0.0, 0.0))
    scene.add_body(None, mass=1.0, inertia=SPIN_INERTIA, angvel=(0.1, omega, 0.1))
    model, params, state = scene.build(dt=dt, integrator=integrator)
    energy0 = float(jnp.sum(rb.kinetic_energy(model, params, state)))
    trace = simulate(model, params, state, _steps(seconds, dt), every, chunk_steps)
    return trace.times, trace.kinetic / energy0 - 1.0, trace


def spin(*, out_dir: Optional[str] = None, log=None, **overrides) -> CaseResult:
    """Case 5: no energy gain while spinning fast about the intermediate axis.

    Args:
        out_dir: folder for ``hard_spin.png``.
        log: optional ``f(str)`` for progress lines.
        **overrides: ``omega`` (rad/s), ``seconds``, ``dt``, ``integrator`` (the
            one judged), ``others`` (reported beside it), ``tolerance`` (max
            relative gain allowed), ``every``, ``chunk_steps``.

    Returns:
        A :class:`CaseResult`; ``measured`` holds each integrator's max relative gain.
    """
    settings = _settings("spin", overrides)
    wall = time.perf_counter()
    rows, curves, compile_s = [], {}, 0.0
    for integrator in (settings["integrator"],) + tuple(i for i in settings["others"]
                                                        if i != settings["integrator"]):
        times, change, trace = spin_energy(integrator, settings["omega"], settings["seconds"], settings["dt"],
                                           settings["every"], settings["chunk_steps"])
        compile_s += trace.compile_s
        gain = float(np.max(change)) if trace.finite else math.inf
        rows.append(dict(integrator=integrator, max_gain=gain, final_change=float(change[-1]),
                         finite=trace.finite))
        curves[integrator] = (times, change)
        _log(log, f"hard spin {integrator:>13}: max E/E0 − 1 = {gain:.3e}, final {float(change[-1]):.3e}")
    judged = rows[0]
    passed = judged["finite"] and judged["max_gain"] <= settings["tolerance"]

    def draw(axes):
        for name, (times, change) in curves.items():
            axes[0].plot(times, np.clip(change, -1.0, 1e3), label=name)
        axes[0].set_yscale("symlog", linthresh=1e-6)
        axes[0].set_xlabel("t (s)")
        axes[0].set_ylabel("E(t)/E₀ − 1 (clipped at 1e3)")
        axes[0].axhline(settings["tolerance"], color="k", ls=":", lw=1)
        axes[0].legend(fontsize=7)

    figure = _save_figure(out_dir, "hard_spin.png", draw)
    text = "; ".join(f"{r['integrator']} {fmt_sci(r['max_gain'])}" for r in rows)
    return CaseResult(
        name="spin", passed=bool(passed), measured={f"{r['integrator']}_max_gain": r["max_gain"] for r in rows},
        measured_text="max E/E₀ − 1: " + text,
        criterion=(f"{settings['integrator']}: max E(t)/E₀ − 1 ≤ {settings['tolerance']:g} over "
                   f"{settings['seconds']:g} s, ω₀ = (0.1, {settings['omega']:g}, 0.1) rad/s about the "
                   f"intermediate axis, dt {fmt_step(settings['dt'])} s"),
        settings=settings, wall_s=time.perf_counter() - wall, compile_s=compile_s, figure=figure, rows=rows)


def overlap_recovery(*, out_dir: Optional[str] = None, log=None, **overrides) -> CaseResult:
    """Case 6: a 2D pyramid started with every box overlapping its neighbours separates gently.

    Args:
        out_dir: folder for ``hard_overlap_recovery.png``.
        log: optional ``f(str)`` for progress lines.
        **overrides: ``rows``, ``overlap`` (fraction of the side), ``seconds``,
            ``build``, ``push_speed`` (v_push, m/s, of the KE bound; module docstring),
            ``overlap_tol`` (m, deepest penetration allowed at the end),
            ``every``, ``chunk_steps``.

    Returns:
        A :class:`CaseResult` with the max and final kinetic energy and the
        initial and final deepest penetration.
    """
    settings = _settings("overlap_recovery", overrides)
    wall = time.perf_counter()
    model, params, state = overlapped_pyramid_scene(settings["rows"], settings["overlap"]).build(**grouped(settings["build"]))
    trace = simulate(model, params, state, _steps(settings["seconds"], float(params.dt)),
                     settings["every"], settings["chunk_steps"])
    total_mass = float(jnp.sum(params.mass))
    rows_of_boxes = np.concatenate([np.full(settings["rows"] - row, row) for row in range(settings["rows"])])
    bound = float(0.5 * np.sum(np.asarray(params.mass) * ((rows_of_boxes + 1) * settings["push_speed"]) ** 2))
    flat = 0.5 * total_mass * settings["push_speed"] ** 2
    initial = rb.detect_contacts(model, params, state)
    initial_pen = float(jnp.max(jnp.where(initial.active, -initial.dist, 0.0)))
    finite = trace.finite
    max_ke = float(np.max(trace.kinetic)) if finite else math.inf
    final_ke = float(trace.kinetic[-1]) if finite else math.inf
    final_pen = float(trace.penetration[-1]) if finite else math.inf
    passed = finite and max_ke <= bound and final_pen < settings["overlap_tol"]
    _log(log, f"hard overlap_recovery {model.num_bodies} boxes: max KE {max_ke:.3g} J (bound {bound:.3g} J), "
              f"final KE {final_ke:.3g} J, penetration {initial_pen * 1000:.1f} → {final_pen * 1000:.3f} mm, "
              f"compile {trace.compile_s:.1f} s, run {trace.run_s:.1f} s")

    def draw(axes):
        axes[0].plot(trace.times, trace.kinetic)
        axes[0].axhline(bound, color="k", ls=":", lw=1, label="bound Σ ½·m·((r+1)·v_push)²")
        axes[0].axhline(flat, color="0.5", ls="--", lw=1, label="½·M·v_push² (scale)")
        axes[0].set_yscale("log")
        axes[0].set_ylabel("total kinetic energy (J)")
        axes[0].legend(fontsize=7)
        axes[1].plot(trace.times, 1000 * trace.penetration)
        axes[1].axhline(1000 * settings["overlap_tol"], color="k", ls=":", lw=1)
        axes[1].set_yscale("symlog", linthresh=0.1)
        axes[1].set_ylabel("deepest penetration (mm)")
        for axis in axes:
            axis.set_xlabel("t (s)")

    figure = _save_figure(out_dir, "hard_overlap_recovery.png", draw, 2)
    return CaseResult(
        name="overlap_recovery", passed=bool(passed),
        measured=dict(max_kinetic_J=max_ke, final_kinetic_J=final_ke, bound_J=bound, flat_bound_J=flat,
                      initial_penetration_m=initial_pen, final_penetration_m=final_pen),
        measured_text=(f"max KE {max_ke:.3g} J (bound {bound:.3g} J; ½·M·v_push² = {flat:.3g} J), "
                       f"final KE {final_ke:.2g} J; "
                       f"penetration {initial_pen * 1000:.1f} → {final_pen * 1000:.3f} mm"),
        criterion=(f"{model.num_bodies}-box 2D pyramid, {settings['overlap'] * 100:g} % overlap: max KE ≤ "
                   f"Σ ½·mᵢ·((rowᵢ+1)·{settings['push_speed']:g} m/s)² and deepest penetration after "
                   f"{settings['seconds']:g} s < {settings['overlap_tol'] * 1000:g} mm"),
        settings=settings, wall_s=time.perf_counter() - wall, compile_s=trace.compile_s, figure=figure,
        rows=[dict(boxes=model.num_bodies, run_s=trace.run_s)])


def long_rest(*, out_dir: Optional[str] = None, log=None, **overrides) -> CaseResult:
    """Case 7: a resting 3D column for ``num_steps`` steps: no NaN, no body moves beyond ``drift_tol``.

    Runs in compiled chunks of ``chunk_steps`` steps; the host keeps only each
    chunk's largest displacement and the top box's height.

    Args:
        out_dir: folder for ``hard_long_rest.png``.
        log: optional ``f(str)`` for progress lines.
        **overrides: ``count`` (boxes), ``num_steps`` (rounded up to whole
            chunks), ``build``, ``drift_tol`` (m), ``every``, ``chunk_steps``.

    Returns:
        A :class:`CaseResult` with the largest displacement and the steps run.
    """
    settings = _settings("long_rest", overrides)
    wall = time.perf_counter()
    model, params, state = column_scene([BOX_MASS] * settings["count"]).build(**grouped(settings["build"]))
    start = np.asarray(state.pos)

    def reduce(summary):
        moved = np.linalg.norm(summary["pos"] - start, axis=-1)  # (samples, n)
        return dict(pos=summary["pos"][-1], vel=summary["vel"][-1], kinetic=np.max(summary["kinetic"]),
                    penetration=np.max(summary["penetration"]), moved=np.max(moved))

    moved = []

    def reduce_and_keep(summary):
        out = reduce(summary)
        moved.append(out.pop("moved"))
        return out

    trace = simulate(model, params, state, settings["num_steps"], settings["every"], settings["chunk_steps"],
                     reduce=reduce_and_keep)
    moved = np.asarray(moved)
    finite = trace.finite
    max_moved = float(np.max(moved)) if finite else math.inf
    passed = finite and max_moved < settings["drift_tol"]
    _log(log, f"hard long_rest {settings['count']} boxes, {trace.steps} steps: max displacement "
              f"{max_moved * 1000:.3f} mm, finite {finite}, compile {trace.compile_s:.1f} s, run {trace.run_s:.1f} s")

    def draw(axes):
        axes[0].plot(trace.times[:len(moved)], 1000 * moved)
        axes[0].axhline(1000 * settings["drift_tol"], color="k", ls=":", lw=1)
        axes[0].set_xlabel("t (s)")
        axes[0].set_ylabel("largest body displacement so far in chunk (mm)")

    figure = _save_figure(out_dir, "hard_long_rest.png", draw)
    return CaseResult(
        name="long_rest", passed=bool(passed),
        measured=dict(max_displacement_m=max_moved, steps=trace.steps, finite=finite,
                      max_penetration_m=float(np.max(trace.penetration)) if finite else math.inf),
        measured_text=(f"{trace.steps} steps: max displacement {max_moved * 1000:.3f} mm, "
                       f"{'no NaN' if finite else 'NON-FINITE'}"),
        criterion=(f"{settings['count']}-box 3D column, ≥ {settings['num_steps']} steps of dt "
                   f"{fmt_step(settings['build']['dt'])} s: finite, every body within "
                   f"{settings['drift_tol'] * 100:g} cm of its start"),
        settings=settings, wall_s=time.perf_counter() - wall, compile_s=trace.compile_s, figure=figure,
        rows=[dict(steps=trace.steps, run_s=trace.run_s)])


CASE_FUNCTIONS = {
    "tallest_stack": tallest_stack,
    "pyramid_2d": pyramid_2d,
    "mass_ratio": mass_ratio,
    "impact": impact,
    "spin": spin,
    "overlap_recovery": overlap_recovery,
    "long_rest": long_rest,
}


def markdown(results) -> str:
    """The hard-case table: case, criterion, measured, pass/fail, times, figure links.

    Args:
        results: a list of :class:`CaseResult`.

    Returns:
        Markdown text (a table, then one image line per figure).
    """
    table = markdown_table(
        ["case", "criterion", "measured", "result", "compile (s)", "wall (s)"],
        [[r.name, r.criterion, r.measured_text, "pass" if r.passed else "**FAIL**",
          fmt_fixed(r.compile_s, 1), fmt_fixed(r.wall_s, 1)] for r in results],
        align=["l", "l", "l", "c", "r", "r"])
    images = [f"![{r.name}]({os.path.basename(r.figure)})" for r in results if r.figure]
    return "\n\n".join([table] + (["\n".join(images)] if images else []))


def hard_cases_section(settings: dict, log=None):
    """Run the hard cases; return ``(markdown, results)``.

    Args:
        settings: per-case overrides, ``{case name: {setting: value}}`` (e.g.
            :data:`QUICK` or :data:`FULL`); a case absent from it is skipped
            unless the dict has no case keys at all, in which case all run at
            their defaults. ``"out_dir"`` (optional) is the folder for the PNGs;
            ``"cases"`` (optional) restricts which cases run.
        log: optional ``f(str)`` for progress lines.

    Returns:
        ``(markdown, results)``: Markdown text (a lead paragraph, the table,
        figure links) and the list of :class:`CaseResult`.
    """
    out_dir = settings.get("out_dir")
    unknown = set(settings) - set(CASES) - {"out_dir", "cases"}
    if unknown:
        raise ValueError(f"hard_cases_section: unknown settings {sorted(unknown)}; valid: case names "
                         f"{list(CASES)}, 'out_dir', 'cases'")
    names = settings.get("cases") or [name for name in CASES if name in settings] or list(CASES)
    results = [CASE_FUNCTIONS[name](out_dir=out_dir, log=log, **settings.get(name, {})) for name in names]
    lead = (
        "Each case is a pass/fail check of a scene that breaks weak solvers (impulse contact, float64, "
        "dt = 1/60 s unless the criterion says otherwise; stacks and pyramids with 8 substeps, the impact "
        "with 4). *Stands* is the issue-3 criterion of tests/test_stacks.py. *compile* counts only the "
        "compiles a case did itself: cases with the same Model share one (0 = cache hit). "
        f"{sum(r.passed for r in results)} of {len(results)} cases pass.")
    return "\n\n".join([lead, markdown(results)]), results
