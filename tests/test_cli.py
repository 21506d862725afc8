"""``jaxrb run``: scene file in, trajectory, animation and report out."""

import json
import pathlib

import numpy as np
import pytest
from PIL import Image

import jaxrb as rb
from jaxrb.cli.main import main
from jaxrb.cli.runner import _segments

ROOT = pathlib.Path(__file__).resolve().parent.parent


def test_run_mjcf_file_writes_trajectory_animation_and_report(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["run", str(ROOT / "examples" / "box_drop.xml"), "--steps", "400", "--every", "10",
                 "--out", str(out)]) == 0
    report = capsys.readouterr().out
    assert "state finite throughout" in report and (out / "report.txt").read_text().strip() == report.strip()
    trajectory = np.load(out / "trajectory.npz")
    assert trajectory["pos"].shape == (41, 1, 3) and trajectory["quat"].shape == (41, 1, 4)
    np.testing.assert_allclose(trajectory["time"][[0, -1]], [0.0, 0.8], atol=1e-6)
    assert trajectory["pos"][0, 0, 2] == pytest.approx(0.5)  # the file's drop height, first state kept
    assert trajectory["pos"][-1, 0, 2] < 0.5  # it fell
    assert Image.open(out / "animation.gif").n_frames == 41


def test_run_json_scene_matches_a_direct_rollout(tmp_path, capsys):
    scene = rb.Scene(dim=2)
    scene.add_plane()
    scene.add_body(rb.Circle(0.1), mass=1.0, pos=(0.0, 1.0), vel=(0.5, 0.0))
    path = tmp_path / "ball.json"
    rb.save_scene(path, scene, dt=0.01, substeps=2)
    assert main(["run", str(path), "--steps", "50", "--out", str(tmp_path / "out"),
                 "--animation", "none"]) == 0
    model, params, state = scene.build(dt=0.01, substeps=2)
    expected = rb.rollout(rb.make_step(model), state, params, 50)
    np.testing.assert_allclose(np.load(tmp_path / "out" / "trajectory.npz")["pos"][1:], expected.pos,
                               rtol=1e-5, atol=1e-6)
    assert not (tmp_path / "out" / "animation.gif").exists()


def test_run_reports_bad_files_and_options(tmp_path, capsys):
    path = tmp_path / "bad.json"
    path.write_text(json.dumps({"format": "jaxrb-scene", "version": 1, "dim": 3,
                                "bodies": [{"shape": {"kind": "sphere", "radius": 0.1}, "mass": -1.0}],
                                "build": {"dt": 0.01}}))
    assert main(["run", str(path), "--steps", "10", "--out", str(tmp_path / "out")]) == 2
    assert "bodies[0].mass" in capsys.readouterr().err
    assert main(["run", str(ROOT / "examples" / "box_drop.xml"), "--steps", "10", "--every", "3",
                 "--out", str(tmp_path / "out")]) == 2
    assert "multiple of --every" in capsys.readouterr().err
    assert main(["run", str(ROOT / "examples" / "box_drop.xml"), "--steps", "10", "--animation", "avi",
                 "--out", str(tmp_path / "out")]) == 2
    assert "gif" in capsys.readouterr().err


@pytest.mark.parametrize("num_steps, every", [(1000, 1), (1000, 5), (7, 1), (60, 20), (1001, 7)])
def test_segments_cover_the_run_in_few_compiled_lengths(num_steps, every):
    if num_steps % every:
        pytest.skip("not a valid run")
    lengths = _segments(num_steps, every)
    assert sum(lengths) == num_steps and all(length % every == 0 for length in lengths)
    assert len(set(lengths)) <= 2 and len(lengths) <= 21


def test_bench_passes_its_options_on(monkeypatch):
    """'jaxrb bench --quick' (the README's command) failed with 'unrecognized arguments: --quick'."""
    import jaxrb.bench.__main__ as bench_main

    seen = []
    monkeypatch.setattr(bench_main, "main", lambda argv: seen.append(argv) or 0)
    assert main(["bench", "--quick", "--only", "contact", "--out", "somewhere"]) == 0
    assert seen == [["--quick", "--only", "contact", "--out", "somewhere"]]
    with pytest.raises(SystemExit):  # other commands still refuse what they do not know
        main(["demo", "--quick"])
