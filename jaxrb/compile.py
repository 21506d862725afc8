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
so they are not set: docs/design.md, 'Ruled out'.)

``import jaxrb`` also sets the same options process-wide in ``XLA_FLAGS``
(:data:`YNN_XLA_FLAG`), so a user's own ``jax.jit`` of a loop over the step
gets them as well, when jaxrb is imported before JAX starts.

Two more CPU settings can only be made process-wide, before JAX compiles
anything, so ``import jaxrb`` makes them (:func:`use_xla_cpu_flags`):

- XLA's threshold for compiling a ``while`` loop as one function
  (``xla_cpu_small_while_loop_byte_threshold``, 1 kB by default). Above the
  threshold, every fused kernel of a loop body is dispatched on its own, and a
  one-world step is dozens of kernels of a few numbers each, so dispatch is
  its cost: raised, a 1 000-step rollout of one tumbling body runs in
  0.09–0.21 ms instead of 0.25–0.85 ms and its gradient in 0.9–1.1 ms
  instead of 12 ms (docs/design.md, 'XLA and LLVM options').
- LLVM's full unrolling limited to loops of at most 4 trips
  (``-unroll-full-max-count=4``, an LLVM option XLA passes on). At one world
  a contact scene's per-row values are loops of a few trips (a box on a
  plane: its 8 corners); LLVM unrolled each into scalar code before its
  loop vectoriser could make it one 8-wide operation. Limited, the penalty
  box drop's one-world rollout ran 1.3–1.5× as fast and its adjoint gradient
  1.5×, with batched programs as fast as before to within 10 %
  (docs/design.md, 'XLA and LLVM options'). It is left out where a GPU or TPU
  plugin for JAX is installed (and ``JAX_PLATFORMS`` is not ``cpu``): XLA
  passes LLVM options to its GPU code generator too, and it was measured on
  CPUs only.

Both change only how loops are compiled, not what they compute, apart from
rounding (fused multiply-adds may be contracted elsewhere, and a vectorised
sum over rows adds in another order, which XLA's reductions allow). Set
``JAXRB_XLA_FLAGS=0`` to leave ``XLA_FLAGS`` alone; a ``XLA_FLAGS`` that
already sets ``xla_backend_extra_options`` is left alone too.

On a GPU, XLA may compute a float32 matrix product in TF32 (a 10-bit
mantissa) unless told otherwise. The box-box narrowphase is written with
``@`` on 3 × 3 frames: on an H200 the penalty 10-box column sank 93 mm in
1 s with such products and 11 mm without (docs/design.md, 'XLA and LLVM
options'; the rest of that fall: 'Penalty contact'). :func:`full_precision` traces a
function with every product at :data:`MATMUL_PRECISION`; ``make_step``'s
step uses it. On CPU it changes nothing: XLA's CPU backend computes float32
products in float32 either way.
"""

from __future__ import annotations

import contextlib
import functools
import os
from typing import Callable

import jax

#: XLA compile options :func:`jit` adds on the CPU backend.
CPU_COMPILER_OPTIONS = {
    "xla_cpu_experimental_ynn_fusion_type": ",".join([
        "LIBRARY_FUSION_TYPE_DOT", "LIBRARY_FUSION_TYPE_INDIVIDUAL_DOT",
        "LIBRARY_FUSION_TYPE_INDIVIDUAL_CONVOLUTION"]),
}


#: XLA's threshold for compiling a ``while`` loop as one function (section 8).
LOOP_THRESHOLD_OPTION = "xla_cpu_small_while_loop_byte_threshold=1000000000"

#: LLVM's full unrolling limited to loops of at most 4 trips (section 47).
UNROLL_LIMIT_OPTION = "-unroll-full-max-count=4"


def accelerator_plugin_installed() -> bool:
    """Whether JAX may run on a GPU or TPU here: a JAX plugin or libtpu is installed and ``JAX_PLATFORMS`` allows it.

    Decided without starting JAX, which would fix ``XLA_FLAGS`` before
    :func:`use_xla_cpu_flags` could add to it.
    """
    import importlib.metadata
    import importlib.util

    if os.environ.get("JAX_PLATFORMS", "").strip().lower() == "cpu":
        return False
    if importlib.util.find_spec("jax_plugins") is not None or importlib.util.find_spec("libtpu") is not None:
        return True
    return bool(importlib.metadata.entry_points(group="jax_plugins"))


def cpu_xla_flag(accelerator: bool) -> str:
    """The ``XLA_FLAGS`` entry :func:`use_xla_cpu_flags` appends: the loop threshold, and the unroll limit unless ``accelerator``."""
    options = [LOOP_THRESHOLD_OPTION] + ([] if accelerator else [UNROLL_LIMIT_OPTION])
    return "--xla_backend_extra_options=" + ",".join(options)


#: What :func:`use_xla_cpu_flags` appends to ``XLA_FLAGS`` in this process.
CPU_XLA_FLAG = cpu_xla_flag(accelerator_plugin_installed())

#: :data:`CPU_COMPILER_OPTIONS` as an ``XLA_FLAGS`` entry, so that a plain
#: ``jax.jit`` gets them too: a user's ``fori_loop`` over ``vmap(step)``
#: compiled with ``jax.jit`` ran the penalty box drop at 1.3 M body-steps/s
#: and the impulse one at 0.32 M without it, 4.4 M and 1.13 M with it
#: (1 024 worlds, 2 cores).
YNN_XLA_FLAG = "".join(f"--{name}={value}" for name, value in CPU_COMPILER_OPTIONS.items())

#: Precision of every matrix product traced under :func:`full_precision`
#: (``jax.default_matmul_precision``'s values; ``None`` leaves JAX's default).
MATMUL_PRECISION = "highest"

#: Set to "0" to keep :func:`use_xla_cpu_flags` from touching ``XLA_FLAGS``.
OPT_OUT_VARIABLE = "JAXRB_XLA_FLAGS"


def use_xla_cpu_flags() -> str:
    """Append :data:`CPU_XLA_FLAG` and :data:`YNN_XLA_FLAG` to ``XLA_FLAGS`` unless the user decided otherwise.

    XLA reads ``XLA_FLAGS`` once, when JAX first compiles or places an array,
    so this takes effect only if that has not happened yet in the process
    (``import jaxrb`` calls it before anything else). It does nothing when
    ``JAXRB_XLA_FLAGS=0`` is set, and leaves out an entry whose option
    ``XLA_FLAGS`` already names.

    Returns:
        What happened, in words, for reports: ``"set"``, ``"opted out"``,
        ``"left to the user's XLA_FLAGS"`` or ``"too late"`` (JAX had
        already started, so the flag was not added).
    """
    flags = os.environ.get("XLA_FLAGS", "")
    if os.environ.get(OPT_OUT_VARIABLE, "1") == "0":
        return "opted out"
    # Each entry is left out where the user's XLA_FLAGS already name its option.
    added = [entry for name, entry in (("xla_backend_extra_options", CPU_XLA_FLAG),
                                       ("xla_cpu_experimental_ynn_fusion_type", YNN_XLA_FLAG))
             if name not in flags]
    if not added:
        return "left to the user's XLA_FLAGS"
    if _backends_started():
        return "too late"
    os.environ["XLA_FLAGS"] = " ".join([flags] + added).strip()
    return "set"


def _backends_started() -> bool:
    try:
        from jax._src import xla_bridge
        return bool(xla_bridge.backends_are_initialized())
    except (ImportError, AttributeError):  # a JAX without this helper: assume not started
        return False


#: What :func:`use_xla_cpu_flags` did when jaxrb was imported (see there).
XLA_FLAGS_STATUS = use_xla_cpu_flags()


def full_precision(fn: Callable) -> Callable:
    """``fn`` traced with every matrix product at :data:`MATMUL_PRECISION`.

    The precision is fixed when ``fn`` is traced (``jax.default_matmul_precision``
    sets each ``dot_general``'s precision as it is recorded), so it holds
    however the caller jits, vmaps or differentiates ``fn``.

    Args:
        fn: any function that JAX traces.

    Returns:
        A function with ``fn``'s signature and name.
    """
    @functools.wraps(fn)
    def traced_at_full_precision(*args, **kwargs):
        precision = MATMUL_PRECISION
        with (jax.default_matmul_precision(precision) if precision else contextlib.nullcontext()):
            return fn(*args, **kwargs)

    return traced_at_full_precision


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
