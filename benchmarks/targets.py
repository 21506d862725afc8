"""The targets of issues 6 and 60 that the peers section measures, checked against its rows.

Speed targets compare a jaxrb row with a peer's at the same batch: the box
drop's in body-steps/s (every engine steps at 2 ms), the stack's and the
pyramid's in simulated body-seconds per second (the engines step at different
h). Each jaxrb setting of a scene is checked against every target of the
scene; a target whose rows are missing (a peer not installed) is NOT
MEASURED, not MISSED.
"""

from __future__ import annotations

import dataclasses
import math
from typing import List, Optional, Sequence

from benchmarks.scenes import LOOP_SUFFIX, PYMUNK_TARGET_BATCH, PeerRow, ratio
from jaxrb.bench.report import fmt_fixed, fmt_sci, fmt_si, fmt_step, markdown_table


@dataclasses.dataclass
class Target:
    """One target (issues 6 and 60): what was measured and whether it was met (``None``: not measured)."""

    scene: str
    text: str
    measured: str
    ok: Optional[bool]

    @property
    def status(self) -> str:
        return "NOT MEASURED" if self.ok is None else ("PASS" if self.ok else "MISSED")


def _find(rows: Sequence[PeerRow], scene: str, engine: str, setting: Optional[str] = None,
          batch: Optional[int] = None) -> Optional[PeerRow]:
    for row in rows:
        if row.scene == scene and row.engine == engine and \
                (setting is None or row.setting == setting) and (batch is None or row.batch == batch):
            return row
    return None


def _speed_target(scene, text, mine, peer, factor, simulated: bool = False) -> Target:
    """``mine`` at least ``factor`` × ``peer``: in body-steps/s, or with ``simulated`` in body-seconds/s.

    Rows of different steps compare only in simulated time (body-s/s = body-steps/s · h).
    """
    if mine is None or peer is None:
        return Target(scene, text, "peer or jaxrb row missing", None)
    rate = (lambda row: row.body_steps_per_s * row.h) if simulated else (lambda row: row.body_steps_per_s)
    value = ratio(rate(mine), rate(peer))
    return Target(scene, text, f"{fmt_fixed(value, 2)}× ({fmt_si(rate(mine))} vs "
                               f"{fmt_si(rate(peer))} {'body-s/s' if simulated else 'body-steps/s'})",
                  bool(value >= factor) if math.isfinite(value) else None)


def _best_flip(rows, h, dtype) -> Optional[PeerRow]:
    candidates = [r for r in rows if r.scene == "flip" and r.engine == "jaxrb" and r.metrics.get("dtype") == dtype
                  and abs(r.h - h) < 1e-12]
    return min(candidates, key=lambda r: r.metrics["flip_error"]) if candidates else None


def evaluate_targets(rows: Sequence[PeerRow]) -> List[Target]:
    """The targets (issues 6 and 60) that this section measures, checked against ``rows``.

    The box-drop, stack and pyramid targets are checked for every jaxrb row of
    the scene (each setting); speed ratios compare rows at the same batch, the
    drop's in body-steps/s (one h), the stack's and pyramid's in simulated
    body-seconds/s (the engines step at different h). A target whose rows
    are missing (peer absent) is NOT MEASURED.

    Args:
        rows: the :class:`PeerRow` results of :func:`run_peers` (or made up, in tests).

    Returns:
        One :class:`Target` per checked clause.
    """
    targets = []
    for mine in [r for r in rows if r.scene == "drop" and r.engine == "jaxrb"]:
        tag = f"box drop, jaxrb {mine.setting}:"
        spring = _find(rows, "drop", "brax_spring", batch=mine.batch)
        mjx_row = _find(rows, "drop", "mjx", batch=mine.batch)
        targets.append(_speed_target("drop", f"{tag} ≥ 5× Brax spring body-steps/s", mine, spring, 5.0))
        targets.append(_speed_target("drop", f"{tag} ≥ 30× MJX body-steps/s", mine, mjx_row, 30.0))
        error = mine.metrics.get("rest_error")
        targets.append(Target("drop", f"{tag} rests within 0.5 mm of 0.1 m",
                              f"{fmt_fixed(1e3 * error, 3)} mm" if error is not None else "—",
                              None if error is None else bool(error <= 5e-4)))
        if spring is None or spring.compile_s is None:
            targets.append(Target("drop", f"{tag} compile ≤ ½ Brax spring's", "Brax spring missing", None))
        else:
            targets.append(Target("drop", f"{tag} compile ≤ ½ Brax spring's",
                                  f"{mine.compile_s:.2f} s vs {spring.compile_s:.2f} s",
                                  bool(mine.compile_s <= 0.5 * spring.compile_s)))
    for loop in [r for r in rows if r.scene == "drop" and r.engine == "jaxrb" and r.setting.endswith(LOOP_SUFFIX)]:
        scanned = _find(rows, "drop", "jaxrb", setting=loop.setting[:-len(LOOP_SUFFIX)], batch=loop.batch)
        text = f"box drop, jaxrb {loop.setting[:-len(LOOP_SUFFIX)]}: user loop within 10 % of rollout"
        value = ratio(loop.body_steps_per_s, scanned.body_steps_per_s if scanned else None)
        targets.append(Target("drop", text, f"{fmt_fixed(value, 2)}×",
                              bool(abs(value - 1.0) <= 0.1) if math.isfinite(value) else None))
    for mine in [r for r in rows if r.scene == "stack" and r.engine == "jaxrb"]:
        tag = f"10-box stack, jaxrb {mine.setting}:"
        sink, drift = mine.metrics["sink"], mine.metrics["drift"]
        seconds = mine.num_steps * mine.h
        targets.append(Target("stack", f"{tag} sinks < 2 mm over {seconds:g} s",
                              f"{1e3 * sink:.3f} mm", bool(abs(sink) < 2e-3)))
        targets.append(Target("stack", f"{tag} drifts < 1 mm over {seconds:g} s",
                              f"{1e3 * drift:.3f} mm", bool(drift < 1e-3)))
        targets.append(_speed_target("stack", f"{tag} ≥ 5× Brax spring body-s/s", mine,
                                     _find(rows, "stack", "brax_spring", batch=mine.batch), 5.0, simulated=True))
    jax2d_row = _find(rows, "pyramid", "jax2d")
    small_batch = jax2d_row.batch if jax2d_row else None
    for small in [r for r in rows if r.scene == "pyramid" and r.engine == "jaxrb"
                  and (small_batch is None or r.batch == small_batch) and r.batch != PYMUNK_TARGET_BATCH]:
        tag = f"pyramid, jaxrb {small.setting}:"
        targets.append(_speed_target("pyramid", f"{tag} ≥ 20× Jax2D body-s/s at the same batch",
                                     small, jax2d_row, 20.0, simulated=True))
        big = _find(rows, "pyramid", "jaxrb", setting=small.setting, batch=PYMUNK_TARGET_BATCH)
        targets.append(_speed_target("pyramid", f"{tag} at batch {PYMUNK_TARGET_BATCH} > pymunk in one world "
                                                 "(body-s/s)", big, _find(rows, "pyramid", "pymunk"), 1.0,
                                     simulated=True))
        targets.append(Target("pyramid", f"{tag} still standing after {small.num_steps * small.h:g} s",
                              f"top box drift {1e3 * small.metrics['drift']:.2f} mm, sink "
                              f"{1e3 * small.metrics['sink']:.2f} mm", bool(small.metrics["stands"])))
    steps = sorted({r.h for r in rows if r.scene == "flip"}, reverse=True)
    if steps:
        best32 = [_best_flip(rows, h, "float32") for h in steps]
        if all(b is not None for b in best32):
            targets.append(Target(
                "flip", "flip in float32: error < 0.005 s at every h (best integrator)",
                "; ".join(f"{fmt_step(h)}: {fmt_sci(b.metrics['flip_error'])} s ({b.setting})"
                          for h, b in zip(steps, best32)),
                all(b.metrics["flip_error"] < 5e-3 for b in best32)))
        parts, oks = [], []
        for h in steps:
            best64, reference = _best_flip(rows, h, "float64"), _find_flip(rows, "mujoco", h)
            if best64 is None or reference is None:
                continue
            mine_error, peer_error = best64.metrics["flip_error"], reference.metrics["flip_error"]
            oks.append(bool(mine_error <= 2.0 * peer_error))
            parts.append(f"{fmt_step(h)}: {fmt_sci(mine_error)} vs {fmt_sci(peer_error)} s")
        targets.append(Target("flip", "flip in float64: within 2× of MuJoCo C's RK4 at the same h",
                              "; ".join(parts) if parts else "MuJoCo C or jaxrb float64 missing",
                              all(oks) if oks else None))
    return targets


def _find_flip(rows, engine, h) -> Optional[PeerRow]:
    for row in rows:
        if row.scene == "flip" and row.engine == engine and abs(row.h - h) < 1e-12:
            return row
    return None


def targets_table(targets: Sequence[Target]) -> str:
    """Markdown table of targets with their measured values and PASS / MISSED / NOT MEASURED."""
    return markdown_table(["target", "measured", "status"],
                          [[t.text, t.measured, f"**{t.status}**"] for t in targets],
                          align=["l", "l", "l"])
