"""rb.jit: jax.jit plus jaxrb's CPU compile options, same results."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxrb as rb
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
