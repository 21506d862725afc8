"""jaxrb beside other engines: the side-by-side runs, the committed report and the GPU runs.

This folder is not part of the jaxrb package (the wheel holds ``jaxrb*`` only,
see pyproject.toml): it is run from a source checkout, at the repository's
root, with the ``peers`` extra (``pip install -e ".[peers]"``: Brax, MJX,
Jax2D, pymunk, pybullet; MuJoCo comes with the ``dev`` extra too). It builds
on :mod:`jaxrb.bench` (scenes, timing, Markdown); nothing in ``jaxrb`` imports
it.

* ``python -m benchmarks [--quick] [--out DIR] [--only SECTION ...]``
  (:mod:`benchmarks.__main__`): the report committed as docs/benchmarks.md,
  every section of ``python -m jaxrb.bench`` and the two below.
* :mod:`benchmarks.peers`: the ``peers`` section: the same scenes in jaxrb,
  MuJoCo C, MJX, Brax, Jax2D and pymunk, with the targets of issues 6 and 60;
  :mod:`benchmarks.peer_gradients` adds its gradient scene (jaxrb, MJX, Brax).
* :mod:`benchmarks.real_data`: the ``real_data`` section: jaxrb fitted to 400
  measured cube tosses and scored beside MuJoCo and Bullet
  (:mod:`benchmarks.toss_peers`).
* ``python -m benchmarks.accelerator`` (:mod:`benchmarks.accelerator`):
  throughput at batches sized for a GPU, written as docs/accelerator.md.

An engine that is not installed is skipped with a note in the report; the
tests of this folder (tests/test_benchmarks_*.py) skip what needs one.
"""
