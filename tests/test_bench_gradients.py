"""The gradient benchmark: a tiny configuration runs, and reverse mode keeps about a State a step."""

import math

import jax
import numpy as np
import pytest

from jaxrb.physics import plane_penalty
from jaxrb.bench import gradients

TINY = dict(gradient_scenes=("tumble",), gradient_memory_steps=(1000,), gradient_time_steps=1000,
            gradient_batch=4, gradient_rounds=2)


@pytest.fixture(scope="module")
def rows():
    # The free-body scene's forward and its three gradients (autodiff, with
    # checkpointing, the adjoint) at one world, then forward, autodiff and
    # adjoint at 4 worlds; the memory rows come from the one-world programs.
    return gradients.run(TINY)


def state_bytes(name):
    """Bytes of one world's floating State (the trajectory stores T of them)."""
    _, _, state = gradients.build(name)
    return sum(leaf.size * leaf.dtype.itemsize for leaf in jax.tree_util.tree_leaves(state)
               if np.issubdtype(leaf.dtype, np.floating))


def test_tiny_run_gives_finite_positive_numbers(rows):
    times = [row for row in rows if row["kind"] == "time"]
    memories = [row for row in rows if row["kind"] == "memory"]
    assert [(row["batch"], row["method"]) for row in times] == [
        (1, "autodiff"), (1, "checkpoint"), (1, "adjoint"), (4, "autodiff"), (4, "adjoint")]
    assert [row["method"] for row in memories] == ["autodiff", "checkpoint", "adjoint"]
    for row in times:
        for key in ("forward_compile_s", "forward_s", "grad_compile_s", "grad_s", "ratio"):
            assert math.isfinite(row[key]) and row[key] > 0, (key, row)
    for row in memories:
        for key in ("temp_bytes", "bytes_per_step", "compile_s"):
            assert math.isfinite(row[key]) and row[key] > 0, (key, row)
    assert memories[1]["segment"] == 25  # the divisor of 1000 nearest √1000 ≈ 31.6 (40 is farther)


def test_gradient_keeps_about_one_state_per_step(rows):
    unchecked, checked, hand_written = [row["temp_bytes"] for row in rows if row["kind"] == "memory"]
    # The loss reads every state, so the backward pass keeps at least the
    # stacked trajectory, T states. Rollout rematerialises each step, so
    # besides it keeps only each step's input state: about two States a step
    # (storing the step's intermediates took 14 States' worth a step).
    assert 1000 * state_bytes("tumble") <= unchecked < 3 * 1000 * state_bytes("tumble")
    assert checked <= unchecked
    # The adjoint keeps the trajectory (every step's input) and a few stacked
    # per-step cotangent factors: a few States' worth a step, no more.
    assert 1000 * state_bytes("tumble") <= hand_written < 6 * 1000 * state_bytes("tumble")


def test_target_table_takes_the_cheapest_method_per_batch(rows):
    targets = gradients.target_rows(rows)
    assert [row["batch"] for row in targets] == [1, 4]
    for target in targets:
        timed = [row for row in rows if row["kind"] == "time" and row["batch"] == target["batch"]]
        assert target["ratio"] == min(row["ratio"] for row in timed)
        assert target["passed"] == (target["ratio"] <= gradients.TARGET_RATIO)


def test_scenes_without_an_adjoint_skip_it():
    step, _, _ = gradients.build("box_bounce")
    assert gradients.methods_for(step, ("autodiff", "adjoint")) == ["autodiff"]


def test_penalty_scene_differentiates_through_its_contact():
    # The full report times this scene; here a short rollout that reaches the
    # plane (it lands after about 0.29 s) checks what it is: the plane-penalty
    # path, with an adjoint, and a finite gradient that the contact's stiffness
    # moves (tests/test_plane_penalty_adjoint.py checks its values).
    step, params, state = gradients.build("box_drop_penalty")
    assert plane_penalty.supports(step.model)
    assert gradients.methods_for(step, ("autodiff", "adjoint")) == ["autodiff", "adjoint"]
    grad = jax.jit(jax.grad(gradients.make_loss(step, 200, "adjoint")))(params, state)
    assert all(np.all(np.isfinite(leaf)) for leaf in jax.tree_util.tree_leaves(grad))
    assert grad.penalty_stiffness != 0.0


def test_markdown_has_one_line_per_row(rows):
    text = gradients.markdown(rows)
    lines = text.splitlines()
    assert lines[0].startswith("| scene") and "grad / forward" in lines[0]
    # A line per row, and one per batch in the target table.
    assert sum(line.startswith("| tumble") for line in lines) == len(rows) + 2
    assert "temp memory" in text and "×" in text and "target" in text


def test_only_the_methods_asked_for_run():
    rows = gradients.run({**TINY, "gradient_methods": ("autodiff",), "gradient_batch": None})
    assert [(row["kind"], row["method"]) for row in rows] == [("time", "autodiff"), ("memory", "autodiff")]
    with pytest.raises(ValueError, match="gradient_methods.*'adjoin'"):
        gradients.run({**TINY, "gradient_methods": ("autodiff", "adjoin")})


def test_unknown_scene_is_a_value_error():
    with pytest.raises(ValueError, match="stack"):
        gradients.build("stack")


@pytest.mark.slow
def test_contact_gradient_keeps_about_one_state_per_step():
    # The impulse-contact gradient takes about a minute to compile. Storing the
    # step's intermediates took 245 States' worth a step.
    unchecked = gradients.gradient_memory("box_bounce", 1000, "autodiff")
    assert 1000 * state_bytes("box_bounce") <= unchecked["temp_bytes"] < 3 * 1000 * state_bytes("box_bounce")
