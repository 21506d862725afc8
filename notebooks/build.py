"""Make the notebooks from the example scripts, check them, or execute them.

Each notebook here is generated from ``examples/<name>.py``, a script in the
"percent" format: ``# %%`` starts a code cell and ``# %% [markdown]`` a
Markdown cell whose lines are comments. One source, so the scripts and the
notebooks cannot drift apart; the notebooks are committed without outputs.

    python notebooks/build.py                    # rewrite notebooks/*.ipynb from examples/
    python notebooks/build.py --check            # fail if a notebook is stale or has outputs
    python notebooks/build.py --execute OUT_DIR  # run every notebook, save executed copies

Needs ``nbformat`` (and ``nbclient`` + ``ipykernel`` to execute): ``pip install -e ".[dev]"``.
"""

from __future__ import annotations

import argparse
import os
import pathlib
import sys

import nbformat

ROOT = pathlib.Path(__file__).resolve().parent.parent
NOTEBOOKS = ("quickstart", "dzhanibekov", "contact_models", "system_identification",
             "parameter_sweep", "speed_vs_error", "cube_tosses", "elbow_tosses", "joints_chain", "gym_hopper")


def cells_of(script: str) -> list:
    """Split a percent-format script into (kind, source) cells; kind is "code" or "markdown"."""
    cells, kind, lines = [], None, []

    def flush():
        text = "\n".join(lines).strip("\n")
        if kind is not None and text:
            cells.append((kind, text))

    for line in script.splitlines():
        if line.startswith("# %%"):
            flush()
            kind, lines = ("markdown" if "[markdown]" in line else "code"), []
        elif kind == "markdown":
            lines.append(line[2:] if line.startswith("# ") else line.lstrip("#"))
        elif kind is not None:
            lines.append(line)
    flush()
    return cells


def notebook_of(name: str) -> nbformat.NotebookNode:
    """The output-free notebook for ``examples/<name>.py``."""
    script = (ROOT / "examples" / f"{name}.py").read_text()
    cells = [nbformat.v4.new_markdown_cell(text) if kind == "markdown" else nbformat.v4.new_code_cell(text)
             for kind, text in cells_of(script)]
    for index, cell in enumerate(cells):
        cell["id"] = f"{name}-{index}"  # stable ids keep rebuilt notebooks byte-identical
    notebook = nbformat.v4.new_notebook(cells=cells)
    notebook.metadata.update({"kernelspec": {"name": "python3", "display_name": "Python 3",
                                             "language": "python"},
                              "language_info": {"name": "python"}})
    return notebook


def text_of(notebook) -> str:
    return nbformat.writes(notebook) + "\n"


def stale_notebooks() -> list:
    """Names whose committed notebook differs from the one their script makes (or has outputs)."""
    return [name for name in NOTEBOOKS
            if not (ROOT / "notebooks" / f"{name}.ipynb").exists()
            or (ROOT / "notebooks" / f"{name}.ipynb").read_text() != text_of(notebook_of(name))]


def execute(name: str, out_dir: pathlib.Path, timeout: int = 600) -> pathlib.Path:
    """Run ``notebooks/<name>.ipynb`` in a fresh kernel; save the executed copy in ``out_dir``.

    The kernel's working directory is ``out_dir``, so the pictures the notebook
    writes (under ``out/``) land beside the executed copy. Raises
    ``nbclient.exceptions.CellExecutionError`` if a cell fails.
    """
    from nbclient import NotebookClient

    out_dir.mkdir(parents=True, exist_ok=True)
    notebook = nbformat.read(ROOT / "notebooks" / f"{name}.ipynb", as_version=4)
    NotebookClient(notebook, timeout=timeout, kernel_name="python3",
                   resources={"metadata": {"path": str(out_dir)}}).execute()
    target = out_dir / f"{name}.ipynb"
    nbformat.write(notebook, target)
    return target


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--check", action="store_true", help="fail if a notebook is stale")
    group.add_argument("--execute", metavar="OUT_DIR", help="execute every notebook into OUT_DIR")
    parser.add_argument("names", nargs="*", default=list(NOTEBOOKS), help="notebooks (default: all)")
    args = parser.parse_args(argv)
    if args.check:
        stale = stale_notebooks()
        for name in stale:
            print(f"notebooks/{name}.ipynb is stale: run python notebooks/build.py", file=sys.stderr)
        return 1 if stale else 0
    if args.execute:
        for name in args.names:
            print(f"executing {name} ...", flush=True)
            print(f"  wrote {execute(name, pathlib.Path(args.execute).resolve())}")
        return 0
    for name in args.names:
        (ROOT / "notebooks" / f"{name}.ipynb").write_text(text_of(notebook_of(name)))
        print(f"wrote notebooks/{name}.ipynb")
    return 0


if __name__ == "__main__":
    os.environ.setdefault("MPLBACKEND", "Agg")
    sys.exit(main())
