"""The fast-spin hard case: no energy gain while spinning about the intermediate axis.

The case (number 5 of the suite, :mod:`jaxrb.bench.hard_cases`):

5. **spin**: a free body, principal inertia (0.3, 0.35, 0.4) kg m², spinning
   at 100 rad/s about its intermediate axis (ω₀ = (0.1, 100, 0.1) rad/s, the
   small components seed the flip), 10 s at dt = 1/60 s (1.7 rad per step).
   Passes when ``implicit_gyro`` gains no energy: max E(t)/E₀ − 1 ≤ 1e-6 (a
   rounding allowance; a gaining integrator goes far beyond). The other
   integrators are reported beside it.
"""

from __future__ import annotations

import math
import time
from typing import Optional

import jax.numpy as jnp
import numpy as np

import jaxrb as rb
from jaxrb.bench.hard_cases.chunks import simulate
from jaxrb.bench.hard_cases.common import CaseResult, _log, _save_figure, _settings, _steps
from jaxrb.bench.report import fmt_sci, fmt_step

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
