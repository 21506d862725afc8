"""The example scripts and the notebooks made from them run, small (JAXRB_QUICK=1).

Each script runs in its own process, as a user runs it, and must write its
pictures; each notebook runs in a fresh Jupyter kernel (nbclient) and must
finish without a cell error. The notebooks must match their scripts.
"""

import os
import pathlib
import subprocess
import sys

import pytest

ROOT = pathlib.Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "notebooks"))
import build as notebook_build  # noqa: E402  (notebooks/build.py)

#: What each script must write into JAXRB_OUT.
PICTURES = {
    "quickstart": ["quickstart_box.gif", "quickstart_pyramid.png", "quickstart_pyramid.gif"],
    "dzhanibekov": ["dzhanibekov.png"],
    "contact_models": ["contact_bounce.png", "contact_stack.png"],
    "system_identification": ["system_identification.png"],
    "parameter_sweep": ["parameter_sweep.png"],
    "speed_vs_error": ["speed_vs_error.png"],
    "cube_tosses": ["cube_tosses_fit.png", "cube_tosses_errors.png", "cube_tosses_trajectories.png",
                    "cube_tosses.gif"],
    "elbow_tosses": ["elbow_tosses_errors.png", "elbow_tosses_trajectories.png", "elbow_tosses.gif"],
    "sysid_bounce": [],
    "joints_chain": ["joints_chain_energy.png", "joints_chain.gif", "newtons_cradle.gif"],
    "gym_hopper": ["gym_hopper_torso.png", "gym_hopper.png", "gym_hopper.gif"],
}


def quick_env(out_dir):
    return dict(os.environ, JAXRB_QUICK="1", JAXRB_OUT=str(out_dir), JAX_PLATFORMS="cpu")


def test_every_notebook_has_a_script_and_is_up_to_date():
    assert set(notebook_build.NOTEBOOKS) <= set(PICTURES)
    assert notebook_build.stale_notebooks() == [], "run: python notebooks/build.py"
    scripts = {path.stem for path in (ROOT / "examples").glob("*.py")}
    assert scripts == set(PICTURES), "every example script is listed (and so tested) here"


def test_percent_format_cells():
    cells = notebook_build.cells_of("# %% [markdown]\n# # Title\n#\n# text\n\n# %%\nx = 1\n\n\n# %%\n")
    assert cells == [("markdown", "# Title\n\ntext"), ("code", "x = 1")]


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(PICTURES))
def test_example_script_runs(name, tmp_path):
    result = subprocess.run([sys.executable, str(ROOT / "examples" / f"{name}.py")], cwd=tmp_path,
                            env=dict(quick_env(tmp_path / "out"), MPLBACKEND="Agg"), capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr[-3000:]
    for picture in PICTURES[name]:
        assert (tmp_path / "out" / picture).stat().st_size > 1000, picture


@pytest.mark.slow
@pytest.mark.parametrize("name", notebook_build.NOTEBOOKS)
def test_notebook_executes(name, tmp_path, monkeypatch):
    pytest.importorskip("nbclient")
    for key, value in quick_env(tmp_path / "out").items():
        monkeypatch.setenv(key, value)  # the kernel inherits this process's environment
    monkeypatch.delenv("MPLBACKEND", raising=False)  # the kernel's own inline backend shows figures
    executed = notebook_build.execute(name, tmp_path)
    import nbformat

    notebook = nbformat.read(executed, as_version=4)
    outputs = [output for cell in notebook.cells if cell.cell_type == "code" for output in cell.outputs]
    assert not [output for output in outputs if output.output_type == "error"]
    # Figures display inline (image/png) and animations as HTML.
    kinds = {key for output in outputs for key in output.get("data", {})}
    assert "image/png" in kinds
    if name == "quickstart":
        assert "text/html" in kinds  # the animations, as JavaScript players
