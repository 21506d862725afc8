"""The peers benchmark: a tiny run with whatever peers are installed, and the ratio/target logic.

In the dev environment MuJoCo is installed and Brax, MJX, Jax2D and pymunk are
not: the section must then run MuJoCo C beside jaxrb and name every absent
peer in a note. Where a peer is installed it must produce rows instead.
"""

import importlib.util
import math

import numpy as np
import pytest

from benchmarks import jaxrb_runs, peer_runs, peers, scenes, targets
from jaxrb import compile as rb_compile
from jaxrb.bench import contact

GRAVITY = 9.81
TINY = dict(peers_scenes=("drop", "flip"), peers_engines=scenes.ENGINES, peers_drop_batch=2,
            peers_drop_steps=20, peers_mujoco_worlds=2,
            peers_drop_jaxrb=(("impulse", 4 * scenes.PEER_STEP, 4), ("penalty", scenes.PEER_STEP, 1)),
            peers_flip_steps=(1 / 60,), peers_flip_horizon=4.0, peers_flip_configs=(("rk4", None),),
            peers_stack_jaxrb=("impulse",), peers_pyramid_jaxrb=("impulse",), peers_repeats=1, peers_budget_s=0.5)
MODULE_OF = {"mujoco": "mujoco", "mjx": "mujoco.mjx", "brax_spring": "brax", "brax_positional": "brax",
             "jax2d": "jax2d", "pymunk": "pymunk"}


def installed(engine):
    try:
        return importlib.util.find_spec(MODULE_OF[engine]) is not None
    except ModuleNotFoundError:  # mujoco.mjx when mujoco itself is absent
        return False


@pytest.fixture(scope="module")
def section():
    """One tiny run of the section (drop and flip scenes; compiled once for the module)."""
    if not installed("mujoco"):
        pytest.skip("mujoco is not installed (it is in the dev extra)")
    return peers.peers_section(TINY)


def free_fall_height(z0, h, steps):
    """Semi-implicit Euler free fall from rest (v += g h, then z += v h): z0 − g h² n(n+1)/2."""
    return z0 - GRAVITY * h * h * steps * (steps + 1) / 2


@pytest.mark.slow  # one shared tiny run of the section: ~15 s idle, ~60 s loaded
def test_absent_peers_are_skipped_with_a_note(section):
    text, results = section
    engines_with_rows = {row.engine for row in results["rows"]}
    for engine in scenes.ENGINES:
        if installed(engine):
            if engine not in ("jax2d", "pymunk"):  # those two only run the pyramid, not in TINY
                assert engine in engines_with_rows, (engine, results["skipped"])
        else:
            assert "not importable" in results["skipped"][engine]
            assert scenes.ENGINE_NAMES[engine] + ": not importable" in text
    if not all(installed(e) for e in scenes.ENGINES):
        assert "**Skipped**" in text and 'pip install -e ".[peers]"' in text


@pytest.mark.slow  # one shared tiny run of the section: ~15 s idle, ~60 s loaded
def test_mujoco_rows_are_there_and_right(section):
    _, results = section
    rows = results["rows"]
    one_world = targets._find(rows, "drop", "mujoco", batch=1)
    many = targets._find(rows, "drop", "mujoco", batch=2)
    assert one_world is not None and many is not None
    # 20 steps of 2 ms is 40 ms of free fall from 0.5 m: a closed form for both engines.
    expected = free_fall_height(scenes.DROP_CENTRE, scenes.PEER_STEP, 20) - scenes.HALF
    assert one_world.metrics["rest_offset"] == pytest.approx(expected, abs=1e-9)
    shifts_up = np.mean(scenes.world_shifts(2, 3)[:, 2])  # the worlds start 0-1 mm higher
    assert many.metrics["rest_offset"] == pytest.approx(expected + shifts_up, abs=1e-9)
    mine = targets._find(rows, "drop", "jaxrb")  # 20 steps of 8 ms, each 4 substeps of 2 ms
    mine_expected = free_fall_height(scenes.DROP_CENTRE, scenes.PEER_STEP, 80) - scenes.HALF
    assert mine.metrics["rest_offset"] == pytest.approx(mine_expected + shifts_up, abs=2e-5)  # float32
    penalty = [r for r in rows if r.engine == "jaxrb" and r.setting.startswith("penalty")]
    # Timed as rollout and as a user's loop over vmap(step): the same step, the same state.
    assert [r.setting.endswith(scenes.LOOP_SUFFIX) for r in penalty] == [False, True]
    for row in penalty:  # 20 steps of 2 ms, no contact yet: the same free fall as MuJoCo's
        assert row.metrics["rest_offset"] == pytest.approx(expected + shifts_up, abs=2e-5)
    for row in (one_world, many, mine, *penalty):
        assert math.isfinite(row.body_steps_per_s) and row.body_steps_per_s > 0
    assert one_world.compile_s is None and mine.compile_s > 0
    flip = targets._find_flip(rows, "mujoco", 1 / 60)
    assert flip.metrics["flips"] == "1/1" and flip.metrics["flip_error"] < 1e-3
    for dtype in ("float32", "float64"):
        assert targets._best_flip(rows, 1 / 60, dtype) is not None


@pytest.mark.slow  # one shared tiny run of the section: ~15 s idle, ~60 s loaded
def test_markdown_is_well_formed(section):
    text, results = section
    assert "**Box drop**" in text and "**Torque-free flip**" in text and "**Issue-6 targets**" in text
    assert "| MuJoCo C" in text
    assert "**Not run with these settings**: 10-box stack, 2D 10-row pyramid (55 boxes), Gradient through contact " \
           "(the full run" in text
    tables = [block for block in text.split("\n\n") if block.startswith("|")]
    assert len(tables) == 3  # drop, flip, targets
    for table in tables:
        lines = table.splitlines()
        counts = {line.replace("\\|", "").count("|") for line in lines}
        assert len(counts) == 1, table  # every line has the same number of cells
        assert set(lines[1].replace("|", "").split()) <= {"-" * n + ":" for n in range(1, 200)} | \
            {":" + "-" * n for n in range(1, 200)}
    # Under jaxrb's unroll limit the peers ran in a process of their own, and the text says so.
    assert ("in a process of their own" in text) == (peers.peer_process_flags() is not None)
    statuses = {t.status for t in results["targets"]}
    assert statuses <= {"PASS", "MISSED", "NOT MEASURED"}
    assert all(f"**{t.status}**" in text for t in results["targets"])


def test_the_note_on_what_was_not_run_names_quick_cuts_and_nothing_for_the_full_run():
    assert "Not run" not in peers.markdown([], {}, peers.FULL)
    quick = peers.markdown([], {}, peers.QUICK)
    assert "**Not run with these settings**: 10-box stack, 2D 10-row pyramid (55 boxes), Gradient through " \
           "contact, Brax positional, Jax2D, pymunk, MJX's flip (the full run has them)." in quick


def test_ratio():
    assert scenes.ratio(10.0, 2.0) == 5.0
    assert math.isnan(scenes.ratio(1.0, 0.0))
    assert math.isnan(scenes.ratio(None, 1.0))
    assert math.isnan(scenes.ratio(float("inf"), 1.0))


def row(scene, engine, rate, batch=1024, bodies=1, steps=1000, h=0.002, compile_s=1.0, setting="s", **metrics):
    """A made-up result whose body-steps/s is ``rate``."""
    return scenes.PeerRow(scene, engine, setting, h, batch, bodies, steps, compile_s,
                          batch * bodies * steps / rate, metrics)


def by_text(checked, words):
    found = [t for t in checked if words in t.text]
    assert len(found) == 1, (words, [t.text for t in checked])
    return found[0]


def test_targets_on_made_up_numbers():
    rows = [
        row("drop", "jaxrb", 5.2e6, compile_s=2.0, rest_offset=-3e-4, rest_error=3e-4),
        row("drop", "brax_spring", 1.06e6, compile_s=4.9, rest_offset=-1.2e-3, rest_error=1.2e-3),
        row("drop", "mjx", 0.034e6, compile_s=7.7, rest_offset=0.0, rest_error=0.0),
        row("stack", "jaxrb", 3.0e5, batch=16, bodies=10, sink=3e-3, drift=2e-4, stands=True),
        row("stack", "brax_spring", 0.5e5, batch=16, bodies=10, sink=0.117, drift=0.0, stands=True),
        row("pyramid", "jaxrb", 0.3e6, batch=16, bodies=55, sink=1e-3, drift=1e-4, stands=True),
        row("pyramid", "jax2d", 11e3, batch=16, bodies=55, sink=5e-2, drift=1e-3, stands=True),
        row("flip", "jaxrb", 1e5, h=1 / 60, setting="a", flip_error=4e-3, dtype="float32"),
        row("flip", "jaxrb", 1e5, h=1 / 60, setting="b", flip_error=9e-3, dtype="float32"),
        row("flip", "jaxrb", 1e5, h=1 / 240, setting="a", flip_error=6e-3, dtype="float32"),
        row("flip", "jaxrb", 1e5, h=1 / 60, setting="a", flip_error=1e-4, dtype="float64"),
        row("flip", "jaxrb", 1e5, h=1 / 240, setting="a", flip_error=3e-6, dtype="float64"),
        row("flip", "mujoco", 1e5, h=1 / 60, setting="RK4", flip_error=6e-5, dtype="float64"),
        row("flip", "mujoco", 1e5, h=1 / 240, setting="RK4", flip_error=2e-6, dtype="float64"),
    ]
    checked = targets.evaluate_targets(rows)
    spring = by_text(checked, "≥ 5× Brax spring body-steps/s")
    assert spring.status == "MISSED" and spring.measured.startswith("4.91×")  # 5.2 / 1.06
    assert by_text(checked, "≥ 30× MJX").status == "PASS"  # 153×
    assert by_text(checked, "rests within 0.5 mm").status == "PASS"
    assert by_text(checked, "compile ≤ ½").status == "PASS"  # 2.0 ≤ 2.45
    assert by_text(checked, "sinks < 2 mm").status == "MISSED"
    assert by_text(checked, "drifts < 1 mm").status == "PASS"
    assert by_text(checked, "≥ 5× Brax spring body-s/s").status == "PASS"  # 6×
    assert by_text(checked, "20× Jax2D").status == "PASS"  # 27×
    assert by_text(checked, "batch 256 > pymunk").status == "NOT MEASURED"
    assert by_text(checked, "still standing").status == "PASS"
    float32 = by_text(checked, "float32")
    assert float32.status == "MISSED" and "4.00e-03" in float32.measured and "6.00e-03" in float32.measured
    assert by_text(checked, "float64").status == "PASS"  # 1e-4 ≤ 1.2e-4 and 3e-6 ≤ 4e-6

    rows[0] = row("drop", "jaxrb", 5.4e6, compile_s=2.5, rest_offset=6e-4, rest_error=6e-4)
    rows[10] = row("flip", "jaxrb", 1e5, h=1 / 60, setting="a", flip_error=2e-4, dtype="float64")
    checked = targets.evaluate_targets(rows)
    assert by_text(checked, "≥ 5× Brax spring body-steps/s").status == "PASS"  # 5.09×
    assert by_text(checked, "rests within 0.5 mm").status == "MISSED"
    assert by_text(checked, "compile ≤ ½").status == "MISSED"  # 2.5 > 2.45
    assert by_text(checked, "float64").status == "MISSED"  # 2e-4 > 1.2e-4
    text = targets.targets_table(checked)
    assert "**MISSED**" in text and "**PASS**" in text and "**NOT MEASURED**" in text


def test_every_jaxrb_setting_is_checked_against_the_scene_targets():
    rows = [
        row("stack", "jaxrb", 3.0e5, batch=16, bodies=10, setting="penalty", sink=1e-2, drift=0.0, stands=True),
        row("stack", "jaxrb", 1.0e4, batch=16, bodies=10, setting="impulse", sink=1e-3, drift=1e-4, stands=True),
        row("stack", "brax_spring", 0.5e5, batch=16, bodies=10, sink=0.117, drift=0.0, stands=True),
        row("pyramid", "jaxrb", 6e5, batch=16, bodies=55, setting="penalty", sink=1e-2, drift=1e-3, stands=True),
        row("pyramid", "jaxrb", 8e5, batch=256, bodies=55, setting="penalty", sink=1e-2, drift=1e-3,
            stands=True),
        row("pyramid", "jaxrb", 1e4, batch=16, bodies=55, setting="impulse", sink=1e-3, drift=1e-4, stands=True),
        row("pyramid", "jax2d", 4e3, batch=16, bodies=55, sink=5e-2, drift=1e-3, stands=True),
        row("pyramid", "pymunk", 5e5, batch=1, bodies=55, sink=1e-3, drift=1e-4, stands=True),
    ]
    status = {t.text: t.status for t in targets.evaluate_targets(rows)}
    assert status["10-box stack, jaxrb penalty: sinks < 2 mm over 2 s"] == "MISSED"
    assert status["10-box stack, jaxrb penalty: ≥ 5× Brax spring body-s/s"] == "PASS"  # 6×
    assert status["10-box stack, jaxrb impulse: sinks < 2 mm over 2 s"] == "PASS"
    assert status["10-box stack, jaxrb impulse: ≥ 5× Brax spring body-s/s"] == "MISSED"  # 0.2×
    assert status["pyramid, jaxrb penalty: ≥ 20× Jax2D body-s/s at the same batch"] == "PASS"  # 150×
    assert status["pyramid, jaxrb penalty: at batch 256 > pymunk in one world (body-s/s)"] == "PASS"  # 1.6×
    assert status["pyramid, jaxrb impulse: ≥ 20× Jax2D body-s/s at the same batch"] == "MISSED"  # 2.5×
    assert status["pyramid, jaxrb impulse: at batch 256 > pymunk in one world (body-s/s)"] == "NOT MEASURED"
    with pytest.raises(ValueError, match="unknown jaxrb contact model 'soft'"):
        jaxrb_runs.jaxrb_stack("soft", 1, 0.1, peers.QUICK)


def test_a_broadphase_overflow_is_reported_and_does_not_stand(monkeypatch):
    # 20 pairs for the pyramid's 135 near ones: contacts are dropped, so it must not count as standing.
    monkeypatch.setitem(scenes.STANDING_SETTINGS, "penalty", {"pyramid": (
        scenes.PEER_STEP, 1, dict(contact="penalty", broadphase="spheres", broadphase_capacity=20))})
    result = jaxrb_runs.jaxrb_pyramid("penalty", 1, 10 * scenes.PEER_STEP, dict(peers.QUICK, peers_repeats=1))
    assert result.metrics["overflow"] and not result.metrics["stands"]
    assert "NO (broadphase overflow)" in peers.scene_table("pyramid", [result])


def test_scene_table_gives_jaxrb_over_peer():
    rows = [row("drop", "jaxrb", 4.0e6, setting="mine", rest_offset=1e-4, rest_error=1e-4),
            row("drop", "brax_spring", 1.0e6, rest_offset=-1.2e-3, rest_error=1.2e-3)]
    lines = peers.scene_table("drop", rows).splitlines()
    assert "jaxrb mine b1024 / this" in lines[0]
    assert lines[2].startswith("| jaxrb") and "1.00×" in lines[2]
    assert lines[3].startswith("| Brax spring") and "4.00×" in lines[3] and "-1.200" in lines[3]


def test_failing_peer_becomes_a_note(monkeypatch):
    if not installed("mujoco"):
        pytest.skip("mujoco is not installed")

    def broken(*args, **kwargs):
        raise RuntimeError("boom")

    monkeypatch.setattr(jaxrb_runs, "jaxrb_stack", lambda model, batch, seconds, settings: row(
        "stack", "jaxrb", 1e5, batch=batch, bodies=10, sink=1e-3, drift=1e-4, stands=True))
    monkeypatch.setattr(peer_runs, "mujoco_stack", broken)
    monkeypatch.setattr(peers, "peer_process_flags", lambda flags=None: None)  # the patches hold here only
    text, results = peers.peers_section(dict(TINY, peers_scenes=("stack",), peers_engines=("mujoco",)))
    assert [r.engine for r in results["rows"]] == ["jaxrb"]
    assert "RuntimeError: boom" in results["skipped"]["mujoco (stack)"]
    assert "boom" in text


def test_the_peers_process_drops_only_the_unroll_limit():
    limit, threshold = rb_compile.UNROLL_LIMIT_OPTION, rb_compile.LOOP_THRESHOLD_OPTION
    assert peers.peer_process_flags(f"--a=1 --xla_backend_extra_options={threshold},{limit}") == \
        f"--a=1 --xla_backend_extra_options={threshold}"
    assert peers.peer_process_flags(f"--xla_backend_extra_options={limit},{threshold}") == \
        f"--xla_backend_extra_options={threshold}"
    assert peers.peer_process_flags(f"--xla_backend_extra_options={threshold}") is None
    assert peers.peer_process_flags("") is None


@pytest.mark.slow  # a new interpreter imports jaxrb and JAX: ~5 s
def test_a_peers_process_that_fails_becomes_a_note():
    rows, skipped = peers._run_in_child(dict(peers.FULL, peers_scenes=("cloth",)), "")
    assert rows == [] and "exited with 1" in skipped["peers (cloth)"]


def test_bad_settings_are_value_errors():
    with pytest.raises(ValueError, match="peers_engines"):
        peer_runs.load_peers(["bullet"])
    with pytest.raises(ValueError, match="peers_scenes"):
        peers.run_peers(dict(TINY, peers_scenes=("cloth",)))


def test_mjcf_scenes_match_jaxrb():
    mujoco = pytest.importorskip("mujoco")
    stack = mujoco.MjModel.from_xml_string(scenes.stack_mjcf())
    assert stack.nbody == 1 + scenes.STACK_COUNT and stack.opt.timestep == scenes.PEER_STEP
    np.testing.assert_allclose(stack.body_mass[1:], 1.0)
    np.testing.assert_allclose(stack.qpos0[2::7], [0.1 + 0.2 * i for i in range(scenes.STACK_COUNT)])
    model, _, state = contact.stack3d_scene(scenes.STACK_COUNT).build(dt=1e-3)
    np.testing.assert_allclose(stack.qpos0.reshape(-1, 7)[:, :3], np.asarray(state.pos), atol=1e-12)
    tumbler = mujoco.MjModel.from_xml_string(scenes.tumbler_mjcf(1 / 240))
    np.testing.assert_allclose(tumbler.body_inertia[1], (0.3, 0.35, 0.4))
    assert tumbler.opt.integrator == mujoco.mjtIntegrator.mjINT_RK4
    assert len(scenes.pyramid_centres()) == 55 and scenes.PYRAMID_TOP == 54


def test_world_shifts_are_those_of_the_contact_benchmark():
    _, _, state = contact.drop_scene().build(dt=1e-3)
    batched = contact._batched_state(state, 8)
    np.testing.assert_allclose(np.asarray(batched.pos[:, 0] - state.pos[0]), scenes.world_shifts(8, 3),
                               atol=1e-12)


def test_stack_sink_is_measured_from_the_touching_height_not_the_lifted_start():
    """A world lifted by its shift and resting exactly on the touching height has not sunk."""
    shifts = scenes.world_shifts(4, 3)
    rest = np.array([0.0, 0.0, scenes.STACK_TOP_REST])
    initial = rest + shifts
    final = initial.copy()
    final[:, -1] = scenes.STACK_TOP_REST - 1.5e-3  # every world ends 1.5 mm below touching
    metrics = scenes.stack_metrics(initial, final, scenes.STACK_TOP_REST)
    assert metrics["sink"] == pytest.approx(1.5e-3, abs=1e-12)
    assert metrics["drift"] == 0.0 and metrics["stands"]
    assert scenes.STACK_TOP_REST == pytest.approx(1.9)  # ten 0.2 m boxes: the top centre at 1.9 m


def test_a_column_thrown_up_or_sunk_in_one_world_does_not_stand():
    rest = np.array([[0.0, 0.0, scenes.STACK_TOP_REST]] * 2)
    thrown = rest.copy()
    thrown[1, -1] += 40.0  # straight up, no sideways drift (a too-stiff penalty column did this)
    assert not scenes.stack_metrics(rest, thrown, scenes.STACK_TOP_REST)["stands"]
    sunk = rest.copy()
    sunk[0, -1] -= 1.5 * scenes.STAND_SINK  # one world of two sank 3/4 of a box: the mean (3/8) would pass
    assert not scenes.stack_metrics(rest, sunk, scenes.STACK_TOP_REST)["stands"]
    assert scenes.stack_metrics(rest, rest, scenes.STACK_TOP_REST)["stands"]


def test_the_user_loop_is_checked_against_the_rollout_of_the_same_setting():
    rows = [row("drop", "jaxrb", 8.0e6, setting="penalty, 1/500 s", rest_offset=0.0, rest_error=0.0),
            row("drop", "jaxrb", 7.5e6, setting="penalty, 1/500 s" + scenes.LOOP_SUFFIX, rest_offset=0.0,
                rest_error=0.0),
            row("drop", "jaxrb", 1.0e6, setting="impulse, 1/500 s", rest_offset=0.0, rest_error=0.0),
            row("drop", "jaxrb", 0.8e6, setting="impulse, 1/500 s" + scenes.LOOP_SUFFIX, rest_offset=0.0,
                rest_error=0.0)]
    status = {t.text: (t.status, t.measured) for t in targets.evaluate_targets(rows)}
    assert status["box drop, jaxrb penalty, 1/500 s: user loop within 10 % of rollout"] == ("PASS", "0.94×")
    assert status["box drop, jaxrb impulse, 1/500 s: user loop within 10 % of rollout"] == ("MISSED", "0.80×")


def test_scenes_stepped_at_different_steps_compare_in_simulated_time():
    """pymunk at 1/60 s against jaxrb at 2 ms: 1.6× pymunk's body-steps/s is 0.19× its body-s/s."""
    rows = [row("pyramid", "jaxrb", 8e5, batch=256, bodies=55, setting="penalty", sink=1e-2, drift=1e-3,
                stands=True),
            row("pyramid", "jaxrb", 6e5, batch=16, bodies=55, setting="penalty", sink=1e-2, drift=1e-3, stands=True),
            row("pyramid", "pymunk", 5e5, batch=1, bodies=55, h=1 / 60, sink=1e-3, drift=1e-4, stands=True),
            row("pyramid", "jax2d", 4e3, batch=16, bodies=55, h=1 / 60, sink=5e-2, drift=1e-3, stands=True)]
    status = {t.text: (t.status, t.measured) for t in targets.evaluate_targets(rows)}
    pymunk = status["pyramid, jaxrb penalty: at batch 256 > pymunk in one world (body-s/s)"]
    assert pymunk[0] == "MISSED" and pymunk[1].startswith("0.19×")  # 8e5 · 0.002 / (5e5 / 60)
    jax2d = status["pyramid, jaxrb penalty: ≥ 20× Jax2D body-s/s at the same batch"]
    assert jax2d[0] == "MISSED" and jax2d[1].startswith("18.00×")  # 6e5 · 0.002 / (4e3 / 60)
