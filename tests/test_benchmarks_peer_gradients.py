"""The peers section's gradient scene: jaxrb's rows in free fall against the closed form, and the table.

The peers (MJX, Brax) are not in the dev environment; where they are
installed, the full run measures them (docs/design.md, 'Current figures').
"""

import math

import numpy as np
import pytest

from benchmarks import peer_gradients, peers, scenes

GRAVITY = 9.81
STEPS = 20  # 40 ms of fall from 0.5 m: the box is still 0.39 m above the plane
BATCH = 2


@pytest.fixture(scope="module")
def scene():
    """The gradient scene alone, jaxrb's rows only (each compiled once for the module)."""
    settings = dict(peers_scenes=("gradient",), peers_engines=(), peers_gradient_steps=STEPS,
                    peers_gradient_batch=BATCH, peers_gradient_rounds=3, peers_budget_s=0.5)
    rows, skipped = peers.run_peers(settings)
    return rows, skipped, peers.markdown(rows, skipped, settings)


def free_fall_height_gradient(z0, h, steps):
    """∂loss/∂z0 in free fall: the loss's mean of the 3 position components' squares gives (2/3) mean_t z_t.

    z_t = z0 − g h² t(t+1)/2 after t semi-implicit Euler steps from rest; the
    other terms of the loss do not depend on z0 before the landing.
    """
    t = np.arange(1, steps + 1)
    return 2.0 / 3.0 * np.mean(z0 - GRAVITY * h * h * t * (t + 1) / 2)


@pytest.mark.slow  # compiles jaxrb's three gradients (impulse autodiff ~20 s)
def test_each_jaxrb_row_differentiates_the_stated_loss(scene):
    rows, skipped, _ = scene
    assert not skipped
    assert [(r.engine, r.setting, r.batch) for r in rows] == [
        ("jaxrb", f"{model}, 2 ms, {method}", 1) for model, method in peer_gradients.JAXRB_SETTINGS] + [
        ("jaxrb", "penalty, 2 ms, adjoint", BATCH)]
    # Batched, the loss is the worlds' mean: the heights' entries sum to the mean of each world's
    # closed form, whose worlds start 0-1 mm higher.
    lifted = np.mean(scenes.world_shifts(BATCH, 3)[:, 2])
    for row in rows:
        m = row.metrics
        expected = free_fall_height_gradient(scenes.DROP_CENTRE + (lifted if row.batch > 1 else 0.0),
                                             scenes.PEER_STEP, STEPS)
        assert row.num_steps == STEPS and m["finite"]
        assert m["height_gradient"] == pytest.approx(expected, rel=1e-5)  # float32 sums of 20 terms
        assert m["ratio"] == pytest.approx(row.run_s / m["forward_s"])
        assert row.compile_s > 0 and m["forward_compile_s"] > 0


@pytest.mark.slow  # shares the module's run
def test_the_gradient_table_is_in_the_markdown(scene):
    _, _, text = scene
    assert "**Gradient through contact**" in text and f"for {STEPS} steps" in text
    table = [block for block in text.split("\n\n") if block.startswith("| engine")]
    assert len(table) == 1
    lines = table[0].splitlines()
    assert len(lines) == 2 + len(peer_gradients.JAXRB_SETTINGS) + 1
    assert len({line.count("|") for line in lines}) == 1


def made_up(engine, grad_s, finite=True, setting="s", batch=1):
    return scenes.PeerRow("gradient", engine, setting, scenes.PEER_STEP, batch, 1, 1000, 2.0, grad_s, dict(
        wrt="w", forward_s=grad_s / 4, forward_compile_s=1.0, ratio=4.0, loss=1.0, finite=finite,
        height_gradient=math.nan if not finite else 0.1))


def test_the_table_gives_jaxrb_over_each_engine_at_the_same_batch_and_flags_a_non_finite_gradient():
    rows = [made_up("mjx", 0.2, finite=False), made_up("jaxrb", 0.002, setting="mine"),
            made_up("brax_spring", 0.05), made_up("jaxrb", 0.5, setting="mine", batch=1024),
            made_up("brax_spring", 5.0, batch=1024), made_up("brax_spring", 1.0, batch=64)]
    lines = peer_gradients.gradient_table(rows).splitlines()
    assert "jaxrb mine / this" in lines[0]
    cells = [[cell.strip() for cell in line.strip(" |").split("|")] for line in lines[2:]]
    assert [(c[0], c[2], c[-1]) for c in cells] == [  # by batch, jaxrb first; its speed over the row's
        ("jaxrb", "1", "1.0×"), ("MJX", "1", "100.0×"), ("Brax spring", "1", "25.0×"),
        ("Brax spring", "64", "—"), ("jaxrb", "1024", "1.0×"), ("Brax spring", "1024", "10.0×")]
    assert cells[1][9] == "**NO**" and cells[2][9] == "yes" and cells[2][6] == "4.00×"
