"""The promises the repository makes about itself: README commands and CI."""

import pathlib
import re

ROOT = pathlib.Path(__file__).resolve().parents[1]


def readme_commands():
    text = (ROOT / "README.md").read_text()
    block = re.search(r"```[a-z]*\n(.*?)```", text, re.S).group(1)
    return [line for line in block.splitlines() if line.strip()]


def test_readme_first_block_has_demo_and_test_commands():
    demo, tests = readme_commands()
    assert "jaxrb demo" in demo and "pip install" in demo
    assert "pytest" in tests and ".[dev]" in tests


def test_ci_runs_exactly_the_readme_test_command():
    ci_lines = [line.strip() for line in (ROOT / ".ci" / "run").read_text().splitlines()]
    assert readme_commands()[1] in ci_lines


def test_demo_runs(capsys, tmp_path):
    from jaxrb.cli import main

    assert main(["demo", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "flip times" in out and "range error" in out and "resting height" in out
    assert (tmp_path / "box_drop.png").stat().st_size > 1000
    assert (tmp_path / "box_drop.gif").stat().st_size > 1000


def test_readme_python_examples_run():
    text = (ROOT / "README.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, re.S)
    assert len(blocks) >= 2
    namespace = {}
    for block in blocks:
        exec(compile(block, "README.md", "exec"), namespace)  # noqa: S102 - our own docs
    assert namespace["traj"].pos.shape[0] == 840


def test_readme_and_guide_links_point_at_files():
    for document in ("README.md", "docs/guide.md", "docs/performance.md"):
        text = (ROOT / document).read_text()
        targets = re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", text)
        assert targets, document
        for target in targets:
            if "://" not in target:
                assert (ROOT / document).parent.joinpath(target).exists(), f"{document}: {target}"
