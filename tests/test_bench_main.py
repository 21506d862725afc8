"""``python -m jaxrb.bench``: the section table runs and writes a well-formed report."""

import math
import re

import pytest

from jaxrb.bench import __main__ as bench_main


def test_every_section_has_a_runner_and_a_settings_line(monkeypatch, tmp_path):
    # Only the free-body throughput section runs (a few seconds); the others are
    # checked for being wired in by their names appearing in the settings header.
    monkeypatch.setitem(bench_main.SETTINGS["quick"], "batches", (1, 4))
    monkeypatch.setitem(bench_main.SETTINGS["quick"], "throughput_steps", 50)
    assert bench_main.main(["--quick", "--only", "throughput", "--out", str(tmp_path)]) == 0
    report = (tmp_path / "report.md").read_text()
    assert "## 1. Free-body throughput" in report
    for name in bench_main.SECTIONS:
        assert f"**{name}**" in report, name
    rows = [line for line in report.splitlines() if line.startswith("| semi_implicit")]
    assert len(rows) == 2
    rates = [float(re.search(r"([\d.]+) [kM]?\s*\|\s*$", row).group(1)) for row in rows]
    assert all(math.isfinite(rate) and rate > 0 for rate in rates)


def test_unknown_section_is_refused():
    with pytest.raises(SystemExit):
        bench_main.main(["--only", "nonsense"])
