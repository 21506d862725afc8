"""The gradient benchmark: a tiny configuration runs, and reverse mode keeps about a State a step."""

import math

import jax
import numpy as np
import pytest

from jaxrb.bench import gradients

TINY = dict(gradient_scenes=("tumble",), gradient_memory_steps=(1000,), gradient_time_steps=1000, repeats=2)


@pytest.fixture(scope="module")
def rows():
    # One forward and two gradient compiles (with and without checkpointing) of
    # the free-body scene; the memory rows come from the same compiled programs.
    return gradients.run(TINY)


def state_bytes(name):
    """Bytes of one world's floating State (the trajectory stores T of them)."""
    _, _, state = gradients.build(name)
    return sum(leaf.size * leaf.dtype.itemsize for leaf in jax.tree_util.tree_leaves(state)
               if np.issubdtype(leaf.dtype, np.floating))


def test_tiny_run_gives_finite_positive_numbers(rows):
    times = [row for row in rows if row["kind"] == "time"]
    memories = [row for row in rows if row["kind"] == "memory"]
    assert [(row["scene"], row["checkpoint"]) for row in times] == [("tumble", False), ("tumble", True)]
    assert [(row["num_steps"], row["checkpoint"]) for row in memories] == [(1000, False), (1000, True)]
    for row in times:
        for key in ("forward_compile_s", "forward_s", "grad_compile_s", "grad_s", "ratio"):
            assert math.isfinite(row[key]) and row[key] > 0, (key, row)
    for row in memories:
        for key in ("temp_bytes", "bytes_per_step", "compile_s"):
            assert math.isfinite(row[key]) and row[key] > 0, (key, row)
    assert memories[1]["segment"] == 25  # the divisor of 1000 nearest √1000 ≈ 31.6 (40 is farther)


def test_gradient_keeps_about_one_state_per_step(rows):
    unchecked, checked = [row["temp_bytes"] for row in rows if row["kind"] == "memory"]
    # The loss reads every state, so the backward pass keeps at least the
    # stacked trajectory, T states. Rollout rematerialises each step, so
    # besides it keeps only each step's input state: about two States a step
    # (storing the step's intermediates took 14 States' worth a step).
    assert 1000 * state_bytes("tumble") <= unchecked < 3 * 1000 * state_bytes("tumble")
    assert checked <= unchecked


def test_markdown_has_one_line_per_row(rows):
    text = gradients.markdown(rows)
    lines = text.splitlines()
    assert lines[0].startswith("| scene") and "grad / forward" in lines[0]
    assert sum(line.startswith("| tumble") for line in lines) == len(rows)
    assert "temp memory" in text and "×" in text


def test_unknown_scene_is_a_value_error():
    with pytest.raises(ValueError, match="stack"):
        gradients.build("stack")


@pytest.mark.slow
def test_contact_gradient_keeps_about_one_state_per_step():
    # The impulse-contact gradient takes about a minute to compile. Storing the
    # step's intermediates took 245 States' worth a step.
    unchecked = gradients.gradient_memory("box_bounce", 1000, checkpoint=False)
    assert 1000 * state_bytes("box_bounce") <= unchecked["temp_bytes"] < 3 * 1000 * state_bytes("box_bounce")
