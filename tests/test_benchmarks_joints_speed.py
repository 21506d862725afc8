"""benchmarks/joints_speed.py: the chain is the same model in every engine, the section runs, targets judge ratios."""

import math

import numpy as np
import pytest

from benchmarks import joints_speed
from benchmarks.scenes import PeerRow


def test_jaxrb_chain_is_mujocos_chain():
    """jaxrb's chain and the MJCF the peers read have the same masses, inertias and motion."""
    mujoco = pytest.importorskip("mujoco")
    import jax.numpy as jnp

    import jaxrb as rb

    compiled = mujoco.MjModel.from_xml_string(joints_speed.chain_mjcf())
    data = mujoco.MjData(compiled)
    model, params, state = joints_speed.chain_scene().build(dt=joints_speed.CHAIN_DT, integrator="semi_implicit",
                                                            contact="none", dtype=jnp.float64)
    np.testing.assert_allclose(np.asarray(params.mass), compiled.body_mass[1:], rtol=1e-12)
    step = rb.make_step(model)
    for _ in range(20):  # 0.2 s of falling from horizontal: MuJoCo's Euler, which semi_implicit is
        mujoco.mj_step(compiled, data)
        state = step(state, params)
    qpos, _ = rb.joints.qpos_qvel(model, params, state)
    np.testing.assert_allclose(np.asarray(qpos), data.qpos, atol=1e-9)


def _row(engine, batch, rate, width="native", integrator="semi_implicit", **metrics):
    """A row whose body-steps/s is ``rate`` (10 bodies, 1 step)."""
    metrics = {"width": width, "finite": True, "first_hinge": 0.0, **metrics}
    if engine == "jaxrb":
        metrics["integrator"] = integrator
    return PeerRow("chain", engine, "x", 0.01, batch, 10, 1, 1.0, batch * 10 / rate, metrics)


def test_targets_compare_body_steps_and_take_mjxs_probe_as_a_bound():
    rows = [_row("jaxrb", 1, 1000.0), _row("brax_generalized", 1, 400.0), _row("brax_spring", 1, 1200.0),
            _row("mjx", 1, 50.0, links=10, lower_bound=True), _row("mjx", 1, 1.0, links=6, lower_bound=False)]
    targets = {t.what: t for t in joints_speed.evaluate_targets(rows)}
    brax = targets["chain, native, 1 world, jaxrb semi_implicit: ahead of every Brax pipeline"]
    assert brax.met is False and "Brax spring" in brax.measured  # judged on the fastest pipeline
    mjx = targets["chain, native, 1 world, jaxrb semi_implicit: ≥ 10× MJX"]
    assert mjx.met is True and mjx.measured == "> 20×"  # the 10-link probe only, as a lower bound


def test_the_section_runs_jaxrb_alone():
    settings = dict(joints_models=("chain",), joints_engines=("jaxrb",), joints_floor_engines=("jaxrb",),
                    joints_integrators=("midpoint",), joints_batches=((2, 3),), joints_widths=("native",),
                    joints_repeats=1, joints_min_repeats=1, joints_budget_s=0.0)
    text, results = joints_speed.joints_speed_section(settings, log=lambda line: None)
    (row,) = results["rows"]
    assert row.engine == "jaxrb" and row.batch == 2 and row.metrics["finite"]
    assert row.run_s > 0 and math.isfinite(row.body_steps_per_s)
    assert "| native |      2 | jaxrb midpoint" in text and "Brax" in text  # the peers not run are named


def test_unknown_settings_are_refused():
    with pytest.raises(ValueError, match="joints_models"):
        joints_speed.joints_speed_section(dict(joints_models=("chian",)), log=lambda line: None)
