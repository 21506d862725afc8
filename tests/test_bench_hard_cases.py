"""Hard-case stability suite: every check passes on a small good scene and fails on a broken one.

The broken configurations keep the Model where they can (a soft contact is a
Params field, ``contact_hertz``), so a good run and its broken twin share one
compile through the suite's runner cache; the 3-box column is shared by the
stack, mass-ratio and long-rest checks, the 3-row pyramid by the pyramid and
overlap checks.
"""

import math
import re

import numpy as np
import pytest

from jaxrb.bench import hard_cases as hc

SOFT = dict(contact_hertz=2.0)  # a 2 Hz contact spring: each joint sinks g/ω² ≈ 6 cm
STACK = dict(heights=(3,), required=3, seconds=2.0)
RATIO = dict(ratios=(100.0,), substeps=(8, 16), seconds=2.0)
REST = dict(count=3, num_steps=240)
PYRAMID = dict(rows=3, seconds=2.0)
OVERLAP = dict(rows=3, seconds=2.0)
IMPACT = dict(speeds=(10.0, 30.0), time_of_impact=(False,), required_box_speed=10.0)
SPIN = dict(seconds=1.0, others=())


def test_tallest_stack_passes_and_fails_with_soft_contact():
    good = hc.tallest_stack(**STACK)
    assert good.passed and good.measured["tallest"] == 3, good.measured_text
    assert good.rows[0]["penetration_m"] < hc.PENETRATION_TOL
    broken = hc.tallest_stack(**STACK, build=SOFT)
    assert not broken.passed and broken.measured["tallest"] == 0, broken.measured_text
    assert broken.rows[0]["penetration_m"] > hc.PENETRATION_TOL


def test_mass_ratio_passes_and_fails_with_soft_contact():
    good = hc.mass_ratio(**RATIO)
    assert good.passed and good.rows[0]["substeps"] == 8, good.measured_text
    # A 10 Hz spring is soft at any substep count: every entry is tried and fails.
    broken = hc.mass_ratio(**RATIO, build=dict(contact_hertz=10.0))
    assert not broken.passed and broken.rows[0]["substeps"] == 16, broken.measured_text
    with pytest.raises(ValueError, match="'substeps' setting"):
        hc.mass_ratio(**RATIO, build=dict(substeps=4))


def test_long_rest_passes_and_fails_with_soft_contact():
    good = hc.long_rest(**REST)
    assert good.passed and good.measured["steps"] == 240 and good.measured["finite"], good.measured_text
    assert good.measured["max_displacement_m"] < 0.01
    broken = hc.long_rest(**REST, build=SOFT)
    assert not broken.passed and broken.measured["max_displacement_m"] > 0.01, broken.measured_text


def test_pyramid_passes_and_fails_with_soft_contact():
    good = hc.pyramid_2d(**PYRAMID)
    assert good.passed, good.measured_text
    broken = hc.pyramid_2d(**PYRAMID, build=SOFT)
    assert not broken.passed, broken.measured_text


def test_overlapped_pyramid_starts_with_a_quarter_side_overlap():
    import jax.numpy as jnp
    import jaxrb as rb

    model, params, state = hc.overlapped_pyramid_scene(3, 0.25).build(dt=1 / 60, substeps=8)
    contacts = rb.detect_contacts(model, params, state)
    deepest = float(jnp.max(jnp.where(contacts.active, -contacts.dist, 0.0)))
    assert abs(deepest - 0.05) < 1e-9  # 25 % of the 0.2 m side
    with pytest.raises(ValueError, match="overlap"):
        hc.overlapped_pyramid_scene(3, 1.0)


def test_overlap_recovery_passes_and_fails_without_position_correction():
    good = hc.overlap_recovery(**OVERLAP)
    assert good.passed, good.measured_text
    assert good.measured["initial_penetration_m"] > 0.04
    assert good.measured["final_penetration_m"] < 1e-3
    # A 0.2 Hz contact spring barely pushes: the overlap is still there at the end.
    broken = hc.overlap_recovery(**OVERLAP, build=dict(contact_hertz=0.2))
    assert not broken.passed and broken.measured["final_penetration_m"] > 1e-3, broken.measured_text


@pytest.mark.slow
def test_overlap_recovery_fails_when_push_out_becomes_velocity():
    # Rigid Baumgarte: no relax passes, no push-out cap and no softness (damping
    # ratio 0 makes the bias rate about 1/h), so the overlap is pushed out in
    # about one substep and that velocity stays in the bodies. (Without the
    # cap and relax but with the default soft constraint, KE only doubles:
    # 33.6 J against 16.5 J for 6 boxes, inside the 90 J bound.)
    broken = hc.overlap_recovery(**OVERLAP, build=dict(relax_iterations=0, max_push_velocity=1e3,
                                                       contact_damping_ratio=0.0))
    assert not broken.passed
    assert broken.measured["max_kinetic_J"] > broken.measured["bound_J"], broken.measured_text


def test_impact_holds_and_fails_without_contact():
    good = hc.impact(**IMPACT)
    assert good.passed and good.measured["box_fastest_mps"] == 30.0, good.measured_text
    assert sorted((row["body"], row["speed"]) for row in good.rows) == [
        ("box", 10.0), ("box", 30.0), ("sphere", 10.0), ("sphere", 30.0)]
    assert all(row["final_z"] > 0.05 for row in good.rows)
    broken = hc.impact(**IMPACT, build=dict(contact="none"))
    assert not broken.passed and broken.measured["box_fastest_mps"] == 0.0, broken.measured_text
    assert all(row["final_z"] < 0.0 for row in broken.rows)


def test_spin_passes_with_implicit_gyro_and_fails_with_euler():
    good = hc.spin(**SPIN)
    assert good.passed and good.measured["implicit_gyro_max_gain"] <= 1e-6, good.measured_text
    broken = hc.spin(**{**SPIN, "integrator": "euler"})
    # Explicit Euler at 1.7 rad per step gains energy (16.7 % measured over 3 s).
    assert not broken.passed and broken.measured["euler_max_gain"] > 1e-2, broken.measured_text


def test_unknown_setting_is_a_value_error():
    with pytest.raises(ValueError, match="hieghts"):
        hc.tallest_stack(hieghts=(3,))
    with pytest.raises(ValueError, match="stackk"):
        hc.hard_cases_section({"stackk": {}})


def test_section_markdown_is_well_formed_and_figures_finite(tmp_path):
    # The settings of the tests above: every compile is a cache hit when they ran first.
    settings = {"tallest_stack": STACK, "spin": SPIN, "long_rest": REST, "out_dir": str(tmp_path)}
    text, results = hc.hard_cases_section(settings)
    assert [r.name for r in results] == ["tallest_stack", "spin", "long_rest"]
    lines = text.splitlines()
    header = next(i for i, line in enumerate(lines) if line.startswith("| case"))
    assert re.fullmatch(r"\|[ :|-]+\|", lines[header + 1])
    rows = lines[header + 2:header + 2 + len(results)]
    columns = lines[header].count("|")
    for line, result in zip(rows, results):
        assert line.startswith(f"| {result.name}") and line.count("|") == columns
        assert ("pass" if result.passed else "FAIL") in line
    assert f"{sum(r.passed for r in results)} of {len(results)} cases pass" in text
    for result in results:
        assert result.figure is not None and (tmp_path / result.figure.split("/")[-1]).stat().st_size > 1000
        assert f"]({result.figure.split('/')[-1]})" in text
        assert math.isfinite(result.wall_s) and math.isfinite(result.compile_s)
        for key, value in result.measured.items():
            if isinstance(value, (int, float)):
                assert math.isfinite(value), (result.name, key, value)
    assert np.all([r.passed for r in results])
