"""What every hard case shares: the boxes' constants, the cases' settings and the result type.

:data:`DEFAULTS` holds each case's default settings (FULL mode), :data:`FULL`
and :data:`QUICK` the overrides of the report and of ``--quick``;
:func:`_settings` merges a case's overrides into its defaults. A case returns
a :class:`CaseResult`; :func:`_save_figure` writes its PNG (on a fresh
Figure, no pyplot state), :func:`_steps` turns seconds into steps and
:func:`_log` writes a progress line.
"""

from __future__ import annotations

import dataclasses
import os
from typing import Callable, Optional

HALF = 0.1  # half side of every box (m)
BOX_MASS = 1.0
FRICTION = 0.5
DT = 1.0 / 60.0

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


def _steps(seconds: float, dt: float) -> int:
    return max(1, int(round(seconds / dt)))


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


def _log(log, text):
    if log is not None:
        log(text)
