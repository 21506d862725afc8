"""Hard cases of violent contact: fast impacts on a plane, and a pyramid started deep in overlap.

The cases (numbered as in the suite, :mod:`jaxrb.bench.hard_cases`; here 4 and 6):

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
"""

from __future__ import annotations

import math
import time
from typing import Optional

import jax.numpy as jnp
import numpy as np

import jaxrb as rb
from jaxrb.bench.hard_cases.chunks import simulate
from jaxrb.bench.hard_cases.common import (BOX_MASS, FRICTION, HALF, CaseResult, _log, _save_figure,
                                           _settings, _steps)
from jaxrb.bench.report import fmt_step
from jaxrb.model.options import grouped

REST_TOL = 0.01  # m, impact: |final centre height − 0.1 m| of a body that came to rest


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
