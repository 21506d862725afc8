"""Benchmarks: speed against error, and throughput (``python -m jaxrb.bench``).

* :mod:`jaxrb.bench.speed_error`: error against the closed form against cost
  for every configuration (:mod:`jaxrb.bench.pareto` draws the front); a
  package: ``scenes`` (scenes, closed forms, error measures), ``grid`` (the
  configurations), ``measure`` (running and timing them) and ``section`` (the
  tables, plots and the section).
* :mod:`jaxrb.bench.hard_cases`: stability cases, pass or fail; a package:
  ``common`` (constants, settings, the result), ``chunks`` (compiled rollouts
  in chunks), ``stacks``, ``impacts`` and ``spinning`` (the cases) and
  ``section`` (the table and the section).
* :mod:`jaxrb.bench.timing`: compile time apart from median run time of
  jitted functions (block_until_ready), shared by every benchmark.
* :mod:`jaxrb.bench.report`: Markdown tables, number formats, machine header.
* :mod:`jaxrb.bench.free_body`: torque-free tumbling accuracy per integrator,
  and free-body throughput in body-steps per second.
* :mod:`jaxrb.bench.contact`: contact-scene throughput (impulse and penalty
  models; bounce, slide, drop, 3D stack, 2D pyramid).
* :mod:`jaxrb.bench.gradients`: reverse-mode memory of long rollouts with and
  without checkpointing, and the time of a gradient against a forward run.
* :mod:`jaxrb.bench.smoothing`: gradient bias and spread against the contact
  models' smoothing knobs on the bounce and slide scenes.

Importing this package has no side effects; the command line enables JAX's
float64 mode for its own process. Nothing here imports another engine: jaxrb
beside MuJoCo, MJX, Brax, Jax2D, pymunk and Bullet, the generator of the
committed report (docs/benchmarks.md) and the GPU runs are in the
repository's ``benchmarks/`` folder (``python -m benchmarks``), which builds
on this package and is not part of it.
"""

from jaxrb.bench.report import Report, fmt_fixed, fmt_sci, fmt_si, fmt_step, machine_info, \
    markdown_table
from jaxrb.bench.timing import Stopwatch, Timing, compile_jitted, time_compiled, time_jitted

__all__ = [
    "Report", "Stopwatch", "Timing", "compile_jitted", "fmt_fixed", "fmt_sci", "fmt_si",
    "fmt_step", "machine_info", "markdown_table", "time_compiled", "time_jitted",
]
