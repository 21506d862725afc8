"""The peers section's gradient scene: jaxrb's rows in free fall against the closed form, and the table.

The peers (MJX, Brax) are not in the dev environment; where they are
installed, the full run measures them (docs/performance.md, section 28).
"""

import math

import numpy as np
import pytest

from jaxrb.bench import peer_gradients, peers

GRAVITY = 9.81
STEPS = 20  # 40 ms of fall from 0.5 m: the box is still 0.39 m above the plane


@pytest.fixture(scope="module")
def scene():
    """The gradient scene alone, jaxrb's rows only (each reverse mode compiled once for the module)."""
    settings = dict(peers_scenes=("gradient",), peers_engines=(), peers_gradient_steps=STEPS,
                    peers_gradient_rounds=3, peers_budget_s=0.5)
    rows, skipped = peers.run_peers(settings)
    return rows, skipped, peers.markdown(rows, skipped, settings)


def free_fall_height_gradient(z0, h, steps):
    """∂loss/∂z0 in free fall: the loss's mean of the 3 position components' squares gives (2/3) mean_t z_t.

    z_t = z0 − g h² t(t+1)/2 after t semi-implicit Euler steps from rest; the
    other terms of the loss do not depend on z0 before the landing.
    """
    t = np.arange(1, steps + 1)
    return 2.0 / 3.0 * np.mean(z0 - GRAVITY * h * h * t * (t + 1) / 2)


@pytest.mark.slow  # compiles both of jaxrb's gradients (impulse autodiff ~20 s)
def test_each_jaxrb_row_differentiates_the_stated_loss(scene):
    rows, skipped, _ = scene
    assert not skipped
    assert [(r.engine, r.setting) for r in rows] == [
        ("jaxrb", f"{model}, 2 ms, {method}") for model, method in peer_gradients.JAXRB_SETTINGS]
    expected = free_fall_height_gradient(peers.DROP_CENTRE, peers.PEER_STEP, STEPS)
    for row in rows:
        m = row.metrics
        assert row.num_steps == STEPS and row.batch == 1 and m["finite"]
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
    assert len(lines) == 2 + len(peer_gradients.JAXRB_SETTINGS)
    assert len({line.count("|") for line in lines}) == 1


def made_up(engine, grad_s, finite=True, setting="s"):
    return peers.PeerRow("gradient", engine, setting, peers.PEER_STEP, 1, 1, 1000, 2.0, grad_s, dict(
        wrt="w", forward_s=grad_s / 4, forward_compile_s=1.0, ratio=4.0, loss=1.0, finite=finite,
        height_gradient=math.nan if not finite else 0.1))


def test_the_table_gives_jaxrb_over_each_engine_and_flags_a_non_finite_gradient():
    rows = [made_up("mjx", 0.2, finite=False), made_up("jaxrb", 0.002, setting="mine"),
            made_up("brax_spring", 0.05)]
    lines = peer_gradients.gradient_table(rows).splitlines()
    assert "jaxrb mine / this" in lines[0]
    assert lines[2].startswith("| jaxrb") and lines[2].rstrip(" |").endswith("1.0×")  # jaxrb first
    assert lines[3].startswith("| MJX") and "**NO**" in lines[3] and "100.0×" in lines[3]
    assert lines[4].startswith("| Brax spring") and "25.0×" in lines[4] and "4.00×" in lines[4]
