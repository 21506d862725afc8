"""The hard-case section: which function runs each case, the table of verdicts, and the section.

:func:`hard_cases_section` runs the cases named in its settings
(:data:`CASE_FUNCTIONS`) and :func:`markdown` puts their results in one
table, followed by their figures.
"""

from __future__ import annotations

import os

from jaxrb.bench.hard_cases.common import CASES
from jaxrb.bench.hard_cases.impacts import impact, overlap_recovery
from jaxrb.bench.hard_cases.spinning import spin
from jaxrb.bench.hard_cases.stacks import long_rest, mass_ratio, pyramid_2d, tallest_stack
from jaxrb.bench.report import fmt_fixed, markdown_table

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
