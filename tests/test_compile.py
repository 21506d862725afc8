"""rb.jit: jax.jit plus jaxrb's CPU compile options, same results; the step's products at full precision."""

import jax
import jax.extend.core
import jax.numpy as jnp
import numpy as np
import pytest

import jaxrb as rb
from jaxrb.math import components as vec
from jaxrb.compile import CPU_COMPILER_OPTIONS, compiler_options


def test_options_only_on_cpu_and_all_or_none():
    assert compiler_options("gpu") == ()
    assert compiler_options("cpu") in ((), tuple(sorted(CPU_COMPILER_OPTIONS.items())))


def test_jit_rollout_equals_jax_jit():
    scene = rb.Scene(dim=3)
    scene.add_plane(friction=0.5)
    scene.add_body(rb.Box((0.1, 0.1, 0.1)), mass=1.0, pos=(0.0, 0.0, 0.3), angvel=(1.0, 2.0, 0.5))
    model, params, state = scene.build(dt=1 / 60, substeps=4, contact="penalty")
    step = rb.make_step(model)
    states = jax.tree_util.tree_map(lambda a: jnp.stack([a, a]), state)
    states = states.replace(pos=states.pos.at[1, 0, 2].add(0.05))

    def simulate(s, p):
        return jax.vmap(lambda one: rb.rollout(step, one, p, 60))(s)

    mine, plain = rb.jit(simulate)(states, params), jax.jit(simulate)(states, params)
    # Other fusions may round differently: float64 over 240 substeps of a bouncing box.
    np.testing.assert_allclose(mine.pos, plain.pos, rtol=0.0, atol=1e-9)
    np.testing.assert_allclose(mine.quat, plain.quat, rtol=0.0, atol=1e-9)


def test_jit_passes_arguments_and_user_options_through():
    double = rb.jit(lambda x, n: x * n, static_argnums=1)
    assert float(double(jnp.asarray(2.0), 3)) == 6.0
    # The user's options reach XLA (merged over jaxrb's): an unknown one is refused there.
    with pytest.raises(Exception, match="xla_no_such_option"):
        rb.jit(lambda x: x + 1.0, compiler_options={"xla_no_such_option": "1"})(1.0)


def _status_in_fresh_process(env_updates, prelude=""):
    """What ``import jaxrb`` did to XLA_FLAGS in a new interpreter: (status, XLA_FLAGS)."""
    import os
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items() if k not in ("XLA_FLAGS", "JAXRB_XLA_FLAGS")}
    env.update(env_updates)
    code = (f"{prelude}\nimport os, jaxrb\n"
            "print(jaxrb.compile.XLA_FLAGS_STATUS); print(os.environ.get('XLA_FLAGS', ''))")
    lines = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                           check=True).stdout.splitlines()
    return lines[0], lines[1] if len(lines) > 1 else ""


_BOTH = rb.compile.CPU_XLA_FLAG + " " + rb.compile.YNN_XLA_FLAG
_YNN_OPTION = "--xla_cpu_experimental_ynn_fusion_type=LIBRARY_FUSION_TYPE_DOT"


@pytest.mark.parametrize("env, prelude, status, flags", [
    ({}, "", "set", _BOTH),
    ({"XLA_FLAGS": "--xla_cpu_enable_fast_math=false"}, "", "set", "--xla_cpu_enable_fast_math=false " + _BOTH),
    ({"JAXRB_XLA_FLAGS": "0"}, "", "opted out", ""),
    ({"XLA_FLAGS": "--xla_backend_extra_options=a=1"}, "", "set",
     "--xla_backend_extra_options=a=1 " + rb.compile.YNN_XLA_FLAG),
    ({"XLA_FLAGS": _YNN_OPTION}, "", "set", _YNN_OPTION + " " + rb.compile.CPU_XLA_FLAG),
    ({"XLA_FLAGS": "--xla_backend_extra_options=a=1 " + _YNN_OPTION}, "", "left to the user's XLA_FLAGS",
     "--xla_backend_extra_options=a=1 " + _YNN_OPTION),
    ({}, "import jax.numpy as jnp; jnp.zeros(1).block_until_ready()", "too late", ""),
])
def test_import_sets_the_loop_threshold_only_when_it_can_and_may(env, prelude, status, flags):
    assert _status_in_fresh_process(env, prelude) == (status, flags)


def test_the_unroll_limit_is_left_out_where_an_accelerator_plugin_may_run(tmp_path):
    threshold, limit = rb.compile.LOOP_THRESHOLD_OPTION, rb.compile.UNROLL_LIMIT_OPTION
    assert rb.compile.cpu_xla_flag(False) == f"--xla_backend_extra_options={threshold},{limit}"
    assert rb.compile.cpu_xla_flag(True) == f"--xla_backend_extra_options={threshold}"
    (tmp_path / "jax_plugins").mkdir()  # the namespace package a GPU plugin for JAX installs
    prelude = f"import sys; sys.path.insert(0, {str(tmp_path)!r})"
    ynn = " " + rb.compile.YNN_XLA_FLAG
    assert _status_in_fresh_process({"JAX_PLATFORMS": ""}, prelude) == ("set", rb.compile.cpu_xla_flag(True) + ynn)
    assert _status_in_fresh_process({"JAX_PLATFORMS": "cpu"}, prelude) == ("set", rb.compile.cpu_xla_flag(False) + ynn)


_VECTOR_OPS_CODE = """
import glob, os, sys
import jaxrb as rb
scene = rb.Scene(dim=3)
scene.add_plane(friction=0.5)
scene.add_body(rb.Box((0.1, 0.1, 0.1)), mass=1.0, pos=(0.0, 0.0, 0.0999))
model, params, state = scene.build(dt=2e-3, contact="penalty")
step = rb.make_step(model)
rb.jit(lambda s, p: rb.rollout(step, s, p, 10)).lower(state, params).compile()
text = "".join(open(f).read() for f in glob.glob(os.path.join(sys.argv[1], "*ir-with-opt.ll")))
print(text.count("<8 x float>"))
"""


@pytest.mark.slow  # two new interpreters compile a rollout each: ~10 s
def test_the_unroll_limit_lets_llvm_vectorise_a_box_s_eight_corners(tmp_path):
    """What the limit is for: with it, the 8 contact rows of a box on a plane compile to 8-wide operations.

    Without it LLVM unrolls each 8-trip row loop into scalar code first
    (docs/design.md, 'XLA and LLVM options'), so the count of 8-wide values in the
    compiled one-world rollout's LLVM IR is what shows the limit at work.
    """
    import os
    import subprocess
    import sys

    if jax.default_backend() != "cpu":
        pytest.skip("LLVM IR of the CPU backend")
    if os.path.exists("/proc/cpuinfo") and " avx" not in open("/proc/cpuinfo").read():
        pytest.skip("8 floats make one vector register only with AVX")
    counts = {}
    for name, options in (("limited", [rb.compile.LOOP_THRESHOLD_OPTION, rb.compile.UNROLL_LIMIT_OPTION]),
                          ("unlimited", [rb.compile.LOOP_THRESHOLD_OPTION])):
        dump = tmp_path / name
        flags = f"--xla_dump_to={dump} --xla_backend_extra_options={','.join(options)}"
        env = dict(os.environ, XLA_FLAGS=flags, JAX_PLATFORMS="cpu", JAX_ENABLE_X64="0")
        done = subprocess.run([sys.executable, "-c", _VECTOR_OPS_CODE, str(dump)], env=env,
                              capture_output=True, text=True, check=True)
        counts[name] = int(done.stdout.split()[-1])
    assert counts["limited"] > 10 and counts["limited"] > 2 * counts["unlimited"], counts


def test_the_loop_threshold_compiles_a_rollout_as_one_function():
    """In this process (the flag in XLA_FLAGS before JAX started) a one-body rollout's loop is hoisted.

    jaxrb sets the flag itself in a process of its own; a pytest-xdist worker
    inherits it from the controller, which imported jaxrb first, and its
    status then reads "left to the user's XLA_FLAGS".
    """
    import os

    in_effect = rb.compile.XLA_FLAGS_STATUS in ("set", "left to the user's XLA_FLAGS") and \
        rb.compile.CPU_XLA_FLAG in os.environ.get("XLA_FLAGS", "")
    if not in_effect or jax.default_backend() != "cpu":
        pytest.skip(f"the loop threshold is not in XLA_FLAGS here ({rb.compile.XLA_FLAGS_STATUS})")
    scene = rb.Scene(dim=3, gravity=(0.0, 0.0, 0.0))
    scene.add_body(None, mass=1.0, inertia=(0.3, 0.35, 0.4), angvel=(0.1, 15.0, 0.1))
    model, params, state = scene.build(dt=1 / 240)
    step = rb.make_step(model)
    text = rb.jit(lambda s, p: rb.rollout(step, s, p, 1000)).lower(state, params).compile().as_text()
    assert "xla_cpu_small_call" in text


def _dot_precisions(jaxpr):
    """The precision of every dot_general in ``jaxpr``, sub-jaxprs (loops, conds) included."""
    found = []
    for equation in jaxpr.eqns:
        if equation.primitive.name == "dot_general":
            found.append(equation.params["precision"])
        for sub in jax.extend.core.jaxprs_in_params(equation.params):
            found.extend(_dot_precisions(sub))
    return found


def test_every_product_of_a_step_is_traced_at_full_precision():
    # A GPU may take a float32 product of default precision in TF32; the box-box
    # narrowphase's frames are 3 x 3 products (jaxrb.compile.full_precision).
    scene = rb.Scene(dim=3)
    scene.add_plane()
    for height in (0.1, 0.3):
        scene.add_body(rb.Box((0.1, 0.1, 0.1)), mass=1.0, pos=(0.0, 0.0, height))
    model, params, state = scene.build(dt=1e-3, contact="penalty")
    precisions = _dot_precisions(jax.make_jaxpr(rb.make_step(model))(state, params).jaxpr)
    assert len(precisions) > 10  # the box-box kernel is in the step
    highest = (jax.lax.Precision.HIGHEST, jax.lax.Precision.HIGHEST)
    assert all(p == highest for p in precisions), set(precisions)
    # ...and not by accident: outside the step, JAX's default stands.
    plain = jax.make_jaxpr(lambda a, b: a @ b)(jnp.eye(3), jnp.ones(3)).jaxpr
    assert _dot_precisions(plain) == [None]


def test_values_are_stored_through_a_conditional_only_on_the_cpu():
    # components.materialize: the conditional is the CPU's only kept fusion
    # boundary; on a GPU it split the step into more kernels (docs/design.md,
    # 'Fusion boundaries'), so lowered for CUDA the parts pass through, with no test of dt.
    def stored(x, params):
        doubled, zero, sine = vec.materialize((2.0 * x, 0.0, jnp.sin(x)), params)
        assert zero == 0.0  # a structural zero stays one
        return doubled + sine

    scene = rb.Scene(dim=3)
    scene.add_body(rb.Sphere(0.1), mass=1.0)
    _, params, _ = scene.build(dt=0.01)
    x = jnp.linspace(0.0, 1.0, 4)
    traced = jax.jit(stored).trace(x, params)
    compares = {platform: traced.lower(lowering_platforms=(platform,)).as_text().count("stablehlo.compare")
                for platform in ("cpu", "cuda")}
    assert compares == {"cpu": 1, "cuda": 0}
    np.testing.assert_allclose(jax.jit(stored)(x, params), 2.0 * x + jnp.sin(x), rtol=1e-6)
