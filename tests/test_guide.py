"""The guide (docs/guide/): every ```python block of every page runs, and the pages hang together.

A page's blocks run in order in one namespace, as a reader would paste them into one
session; pages are independent. They run from the repository root (the pages' paths
are relative to it), headless (Agg), and with x64 off as in a fresh Python session
(conftest turns it on for the rest of the suite), so the float32 a reader gets is what
the snippets' own assertions are checked in.
"""

import pathlib
import re

import jax
import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
GUIDE = ROOT / "docs" / "guide"
TASK_PAGES = ("simulate.md", "contact-and-integrators.md", "gradients.md", "fitting.md", "sweeps.md",
              "rendering.md", "mjcf.md", "joints.md")


def python_blocks(path):
    return re.findall(r"```python\n(.*?)```", path.read_text(), re.S)


def run_page(path):
    """Execute the page's Python blocks in order in one namespace; return the namespace."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    namespace = {"__name__": f"guide_{path.stem}"}
    try:
        with jax.enable_x64(False):
            for index, block in enumerate(python_blocks(path), start=1):
                code = compile(block, f"{path.relative_to(ROOT)}, python block {index}", "exec")
                exec(code, namespace)  # noqa: S102 - our own docs
    finally:
        plt.close("all")
    return namespace


def check_fitting(namespace, printed):
    """The measured-motion fit (six tosses) ran to its table and its score, within its budget."""
    assert "penalty_damping =" in printed and "over 6 trajectories" in printed
    assert namespace["fit"].seconds < 240
    # The elbow: joint rows read as the scene's coordinates, scored by the data's protocol.
    assert namespace["data"].qpos.shape == (400, 121, 8) and "over 4 trajectories" in printed


AFTER = {"fitting.md": check_fitting}


def test_guide_holds_the_index_and_one_page_per_task():
    assert sorted(path.name for path in GUIDE.glob("*.md")) == sorted(("README.md",) + TASK_PAGES)
    index = (GUIDE / "README.md").read_text()
    for page in TASK_PAGES:
        assert f"]({page})" in index, page
        assert python_blocks(GUIDE / page), f"{page} has no python block"


def test_constructor_table_states_what_first_users_guessed_wrong():
    """Issue 61: Capsule's half_length was taken for the length, add_plane's solid side was unknown,
    draw's result was taken for a Figure."""
    index = (GUIDE / "README.md").read_text()
    table = index.split("## Constructors on one screen")[1]
    for name in ("rb.Scene(", "scene.add_body(", "scene.add_plane(", "rb.Sphere(", "rb.Box(", "rb.Capsule(",
                 "rb.Circle(", "rb.Polygon(", "rb.PointMasses(", "scene.build(", "rb.Impulse(", "rb.Penalty(",
                 "rb.make_step(", "rb.rollout(", "rb.render.draw(", "rb.render.animate("):
        assert f"`{name}" in table, name
    assert "The solid is `normal·x < offset`" in table
    assert "half the segment" in table
    assert "Returns the matplotlib Axes" in table and "FuncAnimation" in table


@pytest.mark.parametrize("page", ("README.md",) + TASK_PAGES)
def test_guide_page_runs(page, monkeypatch, capsys):
    monkeypatch.chdir(ROOT)
    namespace = run_page(GUIDE / page)
    if page in AFTER:
        AFTER[page](namespace, capsys.readouterr().out)
