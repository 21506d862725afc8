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


def test_tumbling_runs_the_integrator_settings_it_is_given(monkeypatch, tmp_path):
    # One setting over the first flip (at 3.69 s): its row, and no other.
    monkeypatch.setitem(bench_main.SETTINGS["quick"], "tumble_configs", (("rk4_body", None),))
    monkeypatch.setitem(bench_main.SETTINGS["quick"], "tumble_horizon", 5.0)
    assert bench_main.main(["--quick", "--only", "tumbling", "--out", str(tmp_path)]) == 0
    report = (tmp_path / "report.md").read_text()
    assert "**tumbling**: integrators rk4_body, h ∈ {1/60} s" in report
    rows = [line.split("|")[1:-1] for line in report.splitlines() if re.match(r"\| (euler|semi|implicit|rk4)", line)]
    assert [row[0].strip() for row in rows] == ["rk4_body"]
    flips, error_f64, error_f32 = (cell.strip() for cell in rows[0][3:6])
    # Both dtypes find the flip well inside the float32 target of 5 ms.
    assert flips == "1/1" and float(error_f64) < 5e-3 and float(error_f32) < 5e-3


def test_unknown_section_is_refused(capsys):
    with pytest.raises(SystemExit) as exit_info:
        bench_main.main(["--only", "nonsense"])
    assert exit_info.value.code == 2 and "invalid choice: 'nonsense'" in capsys.readouterr().err


@pytest.mark.parametrize("moved", ["peers", "real_data"])
def test_the_sections_with_other_engines_name_where_they_went(moved, capsys, tmp_path):
    # They run from the repository's benchmarks/ folder, which the package does not import.
    with pytest.raises(SystemExit) as exit_info:
        bench_main.main(["--only", "throughput", moved, "--out", str(tmp_path)])
    error = capsys.readouterr().err
    assert exit_info.value.code == 2 and f"python -m benchmarks --only {moved}" in error
    assert not (tmp_path / "report.md").exists()
    assert moved in bench_main.MOVED and moved not in bench_main.SECTIONS


def test_machine_info_reads_the_first_processor_and_its_vector_units(tmp_path):
    from jaxrb.bench import report

    text = ("processor\t: 0\nmodel name\t: Test CPU\ncpu MHz\t\t: 2445.406\ncache size\t: 512 KB\n"
            "flags\t\t: fpu sse4_2 avx avx2 fma\n\nprocessor\t: 1\nmodel name\t: Other CPU\n"
            "flags\t\t: avx512f\n")
    (tmp_path / "cpuinfo").write_text(text)
    fields = report.cpuinfo(str(tmp_path / "cpuinfo"))
    assert fields["model name"] == "Test CPU" and fields["cpu MHz"] == "2445.406"
    assert "avx512f" not in fields["flags"].split()
    assert report.cpuinfo(str(tmp_path / "missing")) == {}
    info = report.machine_info()
    assert {"cpu MHz, cache", "cpu vector extensions"} <= set(info)
    assert all(word in report.VECTOR_FLAGS for word in info["cpu vector extensions"].split()) \
        or info["cpu vector extensions"] == "(none listed)"
