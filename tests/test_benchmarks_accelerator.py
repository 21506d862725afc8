"""``python -m benchmarks.accelerator``: rows are measured, a failing row is reported, the file is written."""

import math
import re

from benchmarks import accelerator

TINY = dict(accelerator.SETTINGS["quick"], free_batches=(2,), drop_batches=(2,), column_batches=(),
            pyramid_batches=(), impulse_batches=(), gradient_scenes=(), steps=10)


def _table_rows(markdown):
    """Body rows of every Markdown table in ``markdown`` (no headers, no separators)."""
    return [line for line in markdown.splitlines()
            if line.startswith("| ") and not line.startswith(("| scene", "| :", "| -"))]


def test_tiny_run_gives_one_finite_row_per_measurement(monkeypatch, tmp_path):
    monkeypatch.setitem(accelerator.SETTINGS, "quick", TINY)
    assert accelerator.main(["--quick", "--out", str(tmp_path)]) == 0
    rows = _table_rows((tmp_path / "accelerator.md").read_text())
    assert [row.split("|")[1].strip() for row in rows] == ["free bodies", "free bodies", "box drop"]
    for row in rows:
        rate = re.search(r"\|\s*([\d.]+) [kMG]?\s*\|[^|]*\|\s*$", row)
        assert rate and math.isfinite(float(rate.group(1))) and float(rate.group(1)) > 0, row
    assert "mm from resting height at 0.02 s" in rows[-1]


def test_a_row_that_raises_is_reported_and_the_rest_still_run(monkeypatch):
    def broken():
        raise RuntimeError("RESOURCE_EXHAUSTED: out of memory\nmore detail")

    real = accelerator.measurements(dict(TINY, drop_batches=()))
    monkeypatch.setattr(accelerator, "measurements", lambda settings: [broken] + real)
    rows = _table_rows(accelerator.run(TINY))
    assert rows[0].startswith("| failed") and "RuntimeError: RESOURCE_EXHAUSTED: out of memory" in rows[0]
    assert "more detail" not in rows[0]
    assert [row.split("|")[1].strip() for row in rows[1:]] == ["free bodies", "free bodies"]


def test_gradient_rows_time_autodiff_and_the_adjoint_at_each_batch():
    settings = dict(TINY, gradient_scenes=("tumble",), gradient_batches=(2,), gradient_steps=5)
    rows = accelerator.gradient_rows(settings, None)
    assert [tuple(row[:3]) for row in rows] == [
        ("tumble", 1, "autodiff"), ("tumble", 1, "adjoint"), ("tumble", 2, "autodiff"), ("tumble", 2, "adjoint")]
    for row in rows:
        forward_ms, gradient_ms, ratio = float(row[4]), float(row[5]), float(row[6].rstrip("×"))
        assert 0 < forward_ms and 0 < gradient_ms and math.isclose(ratio, gradient_ms / forward_ms, rel_tol=0.05), row


def test_only_measures_the_kinds_of_row_asked_for(monkeypatch, tmp_path):
    monkeypatch.setitem(accelerator.SETTINGS, "quick", dict(TINY, gradient_scenes=("tumble",)))
    assert accelerator.main(["--quick", "--only", "drop", "--out", str(tmp_path)]) == 0
    text = (tmp_path / "accelerator.md").read_text()
    assert [row.split("|")[1].strip() for row in _table_rows(text)] == ["box drop"]
    assert "Gradient of a trajectory loss" not in text and "**rows**: drop" in text
