"""``python -m benchmarks``: jaxrb's report with the sections that run other engines added."""

import pytest

from benchmarks import __main__ as benchmarks_main
from jaxrb.bench import __main__ as bench_main


def test_every_section_of_jaxrb_and_the_peers_is_there_in_order():
    assert set(benchmarks_main.SECTIONS) == set(bench_main.SECTIONS) | set(benchmarks_main.EXTRA)
    assert set(benchmarks_main.EXTRA) == set(bench_main.MOVED)
    # jaxrb's own sections keep their order in the full report.
    assert [s for s in benchmarks_main.SECTIONS if s in bench_main.SECTIONS] == list(bench_main.SECTIONS)


def test_the_report_lists_the_peer_sections_settings(monkeypatch, tmp_path):
    # Only the free-body throughput section runs (a few seconds); the peers' sections are wired in
    # when their settings lines are in the header.
    monkeypatch.setitem(bench_main.SETTINGS["quick"], "batches", (1, 4))
    monkeypatch.setitem(bench_main.SETTINGS["quick"], "throughput_steps", 50)
    assert benchmarks_main.main(["--quick", "--only", "throughput", "--out", str(tmp_path)]) == 0
    report = (tmp_path / "report.md").read_text()
    assert "## 1. Free-body throughput" in report
    for name in benchmarks_main.SECTIONS:
        assert f"**{name}**" in report, name


def test_a_peer_section_runs_through_the_command(monkeypatch, tmp_path):
    # The peers section's runner is called with the mode; here a stand-in answers for it.
    calls = []

    def fake(quick, out_dir, log):
        calls.append((quick, out_dir))
        return "peers ran", {}

    monkeypatch.setitem(benchmarks_main.EXTRA, "peers", bench_main.Section("Peers", "info", fake))
    assert benchmarks_main.main(["--quick", "--only", "peers", "--out", str(tmp_path)]) == 0
    assert calls == [(True, str(tmp_path))]
    assert "## 1. Peers\n\npeers ran" in (tmp_path / "report.md").read_text()


def test_unknown_section_is_refused(capsys):
    with pytest.raises(SystemExit) as exit_info:
        benchmarks_main.main(["--only", "cloth"])
    assert exit_info.value.code == 2 and "python -m benchmarks" in capsys.readouterr().err
