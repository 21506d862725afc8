"""``jaxrb.jit``: ``jax.jit`` with the XLA options that suit rigid-body kernels.

A rigid-body step is many small kernels: sums over 3 components or over a
handful of contacts, per world. XLA's CPU backend (jaxlib 0.10) hands such
reductions to the YNNPACK library, one library call each, and under ``vmap``
over 1 024 worlds each call costs 10–170 µs where XLA's own loop fusion of the
same reduction costs a few: measured on 2 cores, the penalty box drop runs at
0.90 M body-steps/s with them and 1.72 M without (compile 1.5 s → 1.3 s), the
impulse box drop at 160 k and 187 k. So on CPU :func:`jit` keeps YNNPACK for
dots and convolutions (where a library wins) and leaves reductions and
elementwise fusions to XLA. On other backends, or where the installed jaxlib
does not know the option, it is plain ``jax.jit``. (XLA's older fusion
emitters, ``xla_cpu_use_fusion_emitters=False``, run batched steps up to 2×
faster but change float32 rounding enough to fail the float32 flip target,
so they are not set: docs/performance.md, section 6.)

``jax.jit`` of a jaxrb function is still correct, only slower on CPU; setting
``XLA_FLAGS=--xla_cpu_experimental_ynn_fusion_type=LIBRARY_FUSION_TYPE_DOT``
before JAX starts has the same effect process-wide.
"""

from __future__ import annotations

import functools
from typing import Callable

import jax

#: XLA compile options :func:`jit` adds on the CPU backend.
CPU_COMPILER_OPTIONS = {
    "xla_cpu_experimental_ynn_fusion_type": ",".join([
        "LIBRARY_FUSION_TYPE_DOT", "LIBRARY_FUSION_TYPE_INDIVIDUAL_DOT",
        "LIBRARY_FUSION_TYPE_INDIVIDUAL_CONVOLUTION"]),
}


@functools.lru_cache(maxsize=None)
def compiler_options(backend: str) -> tuple:
    """The options :func:`jit` adds for ``backend``, as sorted (name, value) pairs.

    Args:
        backend: a JAX backend name, e.g. ``jax.default_backend()``.

    Returns:
        ``CPU_COMPILER_OPTIONS``'s items on ``"cpu"`` when this jaxlib accepts
        them (checked once by compiling a one-line function), else ``()``.
    """
    if backend != "cpu":
        return ()
    options = dict(CPU_COMPILER_OPTIONS)
    try:
        jax.jit(lambda x: x + 1, compiler_options=options).lower(1.0).compile()
    except Exception:  # an older jaxlib: no such option, or no compiler_options argument
        return ()
    return tuple(sorted(options.items()))


def jit(fn: Callable, **jit_kwargs) -> Callable:
    """``jax.jit(fn, **jit_kwargs)`` with :data:`CPU_COMPILER_OPTIONS` on the CPU backend.

    Args:
        fn: the function to compile (e.g. a rollout of ``make_step``'s step).
        **jit_kwargs: passed to ``jax.jit`` (``static_argnums``, ``donate_argnums``,
            ...); ``compiler_options`` given here are merged over jaxrb's.

    Returns:
        The jitted function.
    """
    options = dict(compiler_options(jax.default_backend()))
    options.update(jit_kwargs.pop("compiler_options", None) or {})
    if options:
        jit_kwargs["compiler_options"] = options
    return jax.jit(fn, **jit_kwargs)
