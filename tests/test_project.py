"""The promises the repository makes about itself: README commands and CI."""

import functools
import pathlib
import re

import numpy as np
import pytest

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
    from jaxrb.cli.main import main

    assert main(["demo", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "flip times" in out and "range error" in out and "resting height" in out
    # float32's flip: rk4's error is shown beside rk4_body's, named as the float32 choice.
    assert "Intermediate-axis flip (rk4_body, float32" in out and "the float32 choice" in out
    assert (tmp_path / "box_drop.png").stat().st_size > 1000
    assert (tmp_path / "box_drop.gif").stat().st_size > 1000


def test_readme_python_examples_run():
    text = (ROOT / "README.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, re.S)
    assert len(blocks) >= 2
    namespace = {}
    for block in blocks:
        exec(compile(block, "README.md", "exec"), namespace)  # noqa: S102 - our own docs
    # What the snippets' comments claim. The ball of radius 0.1 m falls from
    # z = 1 m: apexes 0.1 + 0.9·e^(2k); each impulse bounce loses a few tenths
    # of a percent (measured 0.3, 0.6, 0.9 % over the first three), hence 2 %.
    z = np.asarray(namespace["traj"].pos[:, 0, 2])
    assert z.shape == (840,)
    peaks = z[1:-1][(z[1:-1] >= z[:-2]) & (z[1:-1] > z[2:])]
    np.testing.assert_allclose(peaks[:3], 0.1 + 0.9 * 0.8 ** (2 * np.arange(1, 4)), rtol=0.02)
    # The fit starts at 0.7·0.8 = 0.56 and its 20 steps move it most of the way to 0.8.
    fitted, losses = namespace["fitted"], np.asarray(namespace["losses"])
    assert abs(float(fitted.restitution[0]) - 0.8) < 0.08 and losses[-1] < 0.1 * losses[0]
    # The sweep's apex after the first bounce rises with restitution, to 0.1 + 0.9·0.95² at the top.
    apexes = np.asarray(namespace["apexes"])
    assert np.all(np.diff(apexes) > 0)
    np.testing.assert_allclose(apexes[-1], 0.1 + 0.9 * 0.95 ** 2, rtol=0.02)


# Every page of the guide, listed from the folder so a new page is checked too.
LINKING_DOCUMENTS = ("README.md", "docs/design.md", "docs/accelerator.md") + tuple(
    str(path.relative_to(ROOT)) for path in sorted((ROOT / "docs" / "guide").glob("*.md")))


def test_readme_and_guide_links_point_at_files():
    for document in LINKING_DOCUMENTS:
        text = (ROOT / document).read_text()
        targets = re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", text)
        assert targets, document
        for target in targets:
            if "://" not in target:
                assert (ROOT / document).parent.joinpath(target).exists(), f"{document}: {target}"


@functools.lru_cache(maxsize=None)
def heading_anchors(path):
    """The anchors GitHub gives a Markdown file's headings: lower case, punctuation dropped, spaces as hyphens."""
    headings = re.findall(r"^#+ (.+)$", path.read_text(), re.M)
    return {re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-") for heading in headings}


def test_links_to_sections_name_existing_headings():
    checked = 0
    for document in LINKING_DOCUMENTS:
        path = ROOT / document
        for target, anchor in re.findall(r"\]\(([^)#\s]*)#([^)\s]+)\)", path.read_text()):
            if "://" in target:
                continue
            linked = path.parent.joinpath(target) if target else path
            assert anchor in heading_anchors(linked), f"{document}: {target}#{anchor}"
            checked += 1
    assert checked > 10


def test_design_notes_stay_short_and_hold_their_parts():
    """docs/design.md says what holds now, in at most 300 lines (issue 61): the history stays in git."""
    text = (ROOT / "docs" / "design.md").read_text()
    assert len(text.splitlines()) <= 300
    anchors = heading_anchors(ROOT / "docs" / "design.md")
    for part in ("architecture", "speed-rules", "known-bounds", "ruled-out", "defaults-and-why"):
        assert part in anchors, part


@pytest.mark.parametrize("removed", ["performance" + ".md", "guide" + ".md"])
def test_nothing_names_a_removed_document(removed):
    """The diary became docs/design.md and the one-page guide docs/guide/: a mention of either points nowhere."""
    assert not (ROOT / "docs" / removed).exists()
    paths = [ROOT / "README.md", ROOT / "pyproject.toml"]
    for folder, pattern in (("docs", "*.md"), ("jaxrb", "*.py"), ("tests", "*.py"), ("examples", "*.py"),
                            ("notebooks", "*.py"), ("notebooks", "*.ipynb")):
        paths += sorted((ROOT / folder).rglob(pattern))
    named = [str(path.relative_to(ROOT)) for path in paths if removed in path.read_text(errors="replace")]
    assert not named, named
