"""The smoothing benchmark: it runs, its figures are finite, and the knobs do what they claim.

The properties asserted are the ones the full run measured (K = 32, see
``jaxrb/bench/smoothing.py``), checked here on K = 8 worlds.
"""

import math

import numpy as np
import pytest

from jaxrb.bench import smoothing

# 1 mm is the default width; 0.1 mm is left out because its gradient spikes only at a few
# phases of the step, so 8 worlds estimate its spread poorly (std 0.47 at K = 8, 19 at K = 16).
WIDTHS = (1e-3, 3e-3, 1e-2)


@pytest.fixture(scope="module")
def width_rows():
    """Bounce, penalty activation width: one compile, three knob values, 8 worlds."""
    settings = dict(smoothing_worlds=8, smoothing_sweeps=("bounce_penalty_width",),
                    smoothing_knobs={"bounce_penalty_width": WIDTHS})
    return {row.knob: row for row in smoothing.run(settings)}


def test_tiny_configuration_runs_and_every_figure_is_finite(width_rows, tmp_path):
    assert sorted(width_rows) == sorted(WIDTHS)
    for row in width_rows.values():
        assert row.worlds == 8 and row.scene == "bounce" and row.contact == "penalty"
        assert all(math.isfinite(value) for value in row.figures())
        # Closed forms at h₀ = 0.9 ± 1 cm, e = 0.8: ∂A/∂h₀ = e², ∂A/∂e = 2eh₀
        # (the mean over the symmetric window is the value at 0.9).
        np.testing.assert_allclose(row.grad_closed, (0.64, 1.44), rtol=1e-12)
    table = smoothing.format_table(list(width_rows.values()))
    assert table.count("\n| penalty ") == len(WIDTHS)
    path = smoothing.plot(list(width_rows.values()), str(tmp_path / "smoothing.png"))
    with open(path, "rb") as handle:
        assert handle.read(8) == b"\x89PNG\r\n\x1a\n"


def test_wide_activation_smooths_the_bounce_gradient(width_rows):
    """The default w = 1 mm switches the force on within one 1 ms step (travel v·h = 4.2 mm
    at 4.2 m/s), so the apex is a sawtooth in h₀ with period v·h and ∂A/∂h₀ swings over
    the window (measured std 1.9-2.3 for K = 8-32); at w = 1 cm the force ramps over
    several steps (std 3e-4)."""
    sharp, wide = width_rows[1e-3].grad_std[0], width_rows[1e-2].grad_std[0]
    assert sharp > 0.5
    assert wide < 1e-2
    assert wide < 1e-3 * sharp


def test_smoothed_gradient_matches_closed_form(width_rows):
    """At w = 3 mm ≈ v·h the gradient is smooth and close to the closed form ∂A/∂h₀ = e² = 0.64.

    The closed form takes the impact as instantaneous. The default spring
    holds the ball about 17 ms at h = 1 ms, and gravity acting over that
    time takes a share of about g·T/(e·v) ≈ 5 % off the rebound's growth
    with the drop height; measured bias −0.0125 (2 %). 0.02 is 3 % of the
    derivative.
    """
    assert abs(width_rows[3e-3].grad_bias[0]) < 2e-2


def test_value_error_grows_with_the_width(width_rows):
    """A wider activation pushes from farther off and damps over a wider zone: the apex
    error grows from 3 mm (w = 1 mm, mostly the 1 ms step) and 11 mm (3 mm) to 10 cm at
    w = 1 cm."""
    errors = {knob: abs(row.value_error) for knob, row in width_rows.items()}
    assert errors[1e-2] > 3.0 * max(errors[1e-3], errors[3e-3])


@pytest.mark.parametrize("settings, field", [
    (dict(smoothing_worlds=1), "smoothing_worlds"),
    (dict(smoothing_sweeps=("bounce_nothing",)), "smoothing_sweeps"),
])
def test_bad_settings_name_the_field(settings, field):
    with pytest.raises(ValueError, match=field):
        smoothing.run(settings)


@pytest.mark.slow
def test_friction_regularisation_and_impulse_smoothing():
    """Slide, regularised penalty friction, and bounce, impulse σ (two more compiles).

    Measured (K = 32): a larger v_reg makes the box slide farther (value error 1 mm at
    1e-4 m/s, 27 mm at 0.3 m/s) and its ∂d/∂μ smoother (std 6e-4 -> 1e-5 at 0.1 m/s);
    a larger σ makes the ball push off early (apex error 2.4 mm at 0.01 m/s, 13 mm at
    1 m/s) while ∂A/∂e stays within 3 % of 2eh₀ = 1.44.
    """
    settings = dict(smoothing_worlds=8, smoothing_sweeps=("slide_penalty_friction", "bounce_impulse"),
                    smoothing_knobs={"slide_penalty_friction": (1e-4, 0.1, 0.3),
                                     "bounce_impulse": (0.01, 1.0)})
    rows = smoothing.run(settings)
    assert all(math.isfinite(value) for row in rows for value in row.figures())
    slide = {row.knob: row for row in rows if row.sweep == "slide_penalty_friction"}
    bounce = {row.knob: row for row in rows if row.sweep == "bounce_impulse"}
    assert abs(slide[0.3].value_error) > 5.0 * abs(slide[1e-4].value_error)
    assert slide[0.1].grad_std[0] < 0.2 * slide[1e-4].grad_std[0]
    assert abs(bounce[1.0].value_error) > 2.0 * abs(bounce[0.01].value_error)
    for row in bounce.values():
        assert abs(row.grad_bias[1]) < 0.05
