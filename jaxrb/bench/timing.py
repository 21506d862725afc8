"""Timing of jitted functions: compile time apart from the median run time.

Every benchmark in :mod:`jaxrb.bench` times the same way, so numbers from
different reports can be compared:

* **compile**: tracing + lowering + XLA compilation of the function for the
  given arguments (``jax.jit(fn).lower(*args).compile()``), wall seconds. This
  is what a notebook user waits for on the first call.
* **run**: wall seconds of one call of the compiled executable, waited on with
  ``jax.block_until_ready``. One untimed warm-up call comes first; the reported
  figure is the median of the timed calls. Functions whose ratio is the
  figure (a gradient against its forward) are timed in turn, call by call
  (:func:`time_alternated`).

Example::

    timing = time_jitted(lambda s, p: rollout(step, s, p, 1000), state, params)
    print(timing.compile_s, timing.run_s)
"""

from __future__ import annotations

import dataclasses
import statistics
import time
from typing import Any, Callable, Sequence

import jax

from jaxrb.compile import jit
from jaxrb.physics.step import rollout


@dataclasses.dataclass(frozen=True)
class Timing:
    """Compile and run times of one jitted function on one set of arguments.

    Attributes:
        compile_s: trace + lower + compile, seconds.
        run_s: median wall seconds of one call (after a warm-up call).
        runs_s: every timed call, seconds, in order.
        output: the output of the last call (already blocked on), so a
            benchmark can time and check results with one execution.
    """

    compile_s: float
    run_s: float
    runs_s: tuple
    output: Any = dataclasses.field(default=None, repr=False, compare=False)

    @property
    def min_s(self) -> float:
        return min(self.runs_s)

    @property
    def spread(self) -> float:
        """(max − min) / median of the timed runs: a rough noise indicator."""
        return (max(self.runs_s) - min(self.runs_s)) / self.run_s if self.run_s > 0 else 0.0


def compile_jitted(fn: Callable, *args, static_argnums: Sequence[int] = ()):
    """Jit, lower and compile ``fn`` for ``args``; return ``(compiled, seconds)``.

    ``compiled`` is called with the non-static arguments only.
    """
    start = time.perf_counter()
    compiled = jit(fn, static_argnums=tuple(static_argnums)).lower(*args).compile()
    return compiled, time.perf_counter() - start


def time_compiled(compiled: Callable, *args, repeats: int = 5, min_repeats: int = 3,
                  budget_s: float | None = None, warmup: int = 1):
    """Median wall time of ``compiled(*args)`` with ``block_until_ready``.

    Args:
        compiled: a compiled (or jitted) function.
        args: its arguments.
        repeats: number of timed calls at most.
        min_repeats: timed calls made even when ``budget_s`` is exceeded.
        budget_s: optional wall-time budget for the timed calls; once it is
            used up (and ``min_repeats`` calls are done) timing stops early.
        warmup: untimed calls first.

    Returns:
        ``(median_s, runs_s, last_output)``.
    """
    return time_alternated((compiled,), *args, repeats=repeats, min_repeats=min_repeats,
                           budget_s=budget_s, warmup=warmup)[0]


def time_alternated(functions: Sequence[Callable], *args, repeats: int = 5, min_repeats: int = 3,
                    budget_s: float | None = None, warmup: int = 1) -> list:
    """Time several functions of the same arguments call by call in turn, as :func:`time_compiled` times one.

    Each round calls every function once, in order. On a shared host whose
    speed drifts over seconds, functions timed one after the other can land
    in a fast and a slow spell, and their ratio with them; taken in turn,
    they share the spells.

    Args:
        functions: compiled (or jitted) functions, each called as ``f(*args)``.
        args: their arguments.
        repeats: rounds at most; min_repeats, budget_s (summed over every
            function's calls), warmup (untimed rounds first): as in
            :func:`time_compiled`.

    Returns:
        One ``(median_s, runs_s, last_output)`` per function, in order.
    """
    outputs = [None] * len(functions)
    for _ in range(warmup):
        outputs = [jax.block_until_ready(function(*args)) for function in functions]
    runs = [[] for _ in functions]
    spent = 0.0
    for index in range(max(1, repeats)):
        for position, function in enumerate(functions):
            start = time.perf_counter()
            outputs[position] = jax.block_until_ready(function(*args))
            elapsed = time.perf_counter() - start
            runs[position].append(elapsed)
            spent += elapsed
        if budget_s is not None and spent > budget_s and index + 1 >= min_repeats:
            break
    return [(statistics.median(times), tuple(times), output) for times, output in zip(runs, outputs)]


def time_jitted(fn: Callable, *args, repeats: int = 5, min_repeats: int = 3,
                budget_s: float | None = None, warmup: int = 1) -> Timing:
    """Compile ``fn`` for ``args`` and time it; see the module docstring.

    Args:
        fn: a pure function of JAX arrays/pytrees (it is jitted here).
        args: its arguments (pytrees of arrays).
        repeats, min_repeats, budget_s, warmup: see :func:`time_compiled`.

    Returns:
        A :class:`Timing`; ``output`` holds the result of the last call.
    """
    compiled, compile_s = compile_jitted(fn, *args)
    run_s, runs, output = time_compiled(compiled, *args, repeats=repeats, min_repeats=min_repeats,
                                        budget_s=budget_s, warmup=warmup)
    return Timing(compile_s=compile_s, run_s=run_s, runs_s=runs, output=output)


class Stopwatch:
    """Context manager measuring wall seconds: ``with Stopwatch() as sw: ...; sw.seconds``."""

    def __enter__(self):
        self.start = time.perf_counter()
        self.seconds = 0.0
        return self

    def __exit__(self, *exc):
        self.seconds = time.perf_counter() - self.start
        return False


def final_state_fn(step: Callable, num_steps: int, batched: bool = False) -> Callable:
    """``(state, params) -> state`` after ``num_steps`` steps, for timing a step.

    The steps run as :func:`jaxrb.rollout` runs them, so the benchmarks time
    what users run, keeping only the final state so the timing is the step's,
    not a trajectory's. ``batched``: ``state`` has a leading world axis and
    the rollout is ``jax.vmap``-ed over it (params shared).
    """
    def final(state, params):
        states = rollout(step, state, params, num_steps, every=num_steps)
        return jax.tree_util.tree_map(lambda a: a[0], states)

    return jax.vmap(final, in_axes=(0, None)) if batched else final
