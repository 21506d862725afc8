"""Hard cases of stacking and resting: the tallest column, the 2D pyramid, the mass ratio, the long rest.

The cases (numbered as in the suite, :mod:`jaxrb.bench.hard_cases`; here 1–3 and 7):

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
"""

from __future__ import annotations

import math
import time
from typing import Optional

import numpy as np

from jaxrb.bench.contact import column_scene, pyramid2d_scene
from jaxrb.bench.hard_cases.chunks import Trace, simulate
from jaxrb.bench.hard_cases.common import BOX_MASS, CaseResult, _log, _save_figure, _settings, _steps
from jaxrb.bench.report import fmt_step
from jaxrb.model.options import grouped

# Issue-3 "stands" criteria (tests/test_stacks.py).
DRIFT_TOL = 0.01  # m, top box horizontal drift
PENETRATION_TOL = 0.005  # m, deepest contact
SPEED_TOL = 0.01  # m/s, every body in the last second
COLLAPSE_TOL = 0.02  # m, top box height change at the end
STANDS_TEXT = (f"top drift < {DRIFT_TOL * 100:g} cm, penetration < {PENETRATION_TOL * 1000:g} mm, "
               f"speed in last 1 s < {SPEED_TOL * 100:g} cm/s, top within {COLLAPSE_TOL * 100:g} cm of start")


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
