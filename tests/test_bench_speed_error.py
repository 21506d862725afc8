"""The speed-against-error benchmark: a tiny run makes a well-formed report, the Pareto
marks agree with ``pareto_front``, and every error metric is zero on the exact answer
and large on a wrong one."""

import math
import os
import re

import numpy as np
import pytest
from PIL import Image
from scipy.integrate import solve_ivp

from jaxrb import analytic
from jaxrb.bench import speed_error as se
from jaxrb.bench.free_body import sign_changes
from jaxrb.bench.pareto import pareto_front

G = se.GRAVITY

TINY = dict(
    speed_error_scenes=se.SCENE_NAMES,
    speed_error_configs={
        "tumble": se.tumble_grid((1 / 60,), ("float32",), (("rk4", None), ("semi_implicit", "exp_map"))),
        "bounce": [se.penalty(2e-3)],
        "slide": [se.penalty(2e-3)],
        "roll": [se.penalty(2e-3)],
    },
    speed_error_horizons={"tumble": 5.0, "bounce": 2.2, "slide": 0.6, "roll": 0.6},
    speed_error_batch=8, speed_error_batch_steps=5, speed_error_batch_configs="cheapest",
    speed_error_repeats=1,
)


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    out_dir = str(tmp_path_factory.mktemp("speed_error"))
    markdown, results = se.speed_error_section({**TINY, "out_dir": out_dir})
    return markdown, results, out_dir


# --- the tiny run ---------------------------------------------------------------------------

def test_tiny_run_makes_a_well_formed_report(tiny):
    markdown, results, out_dir = tiny
    scenes = results["scenes"]
    assert list(scenes) == list(se.SCENE_NAMES)
    assert markdown.count("\n### ") == 4
    headers = re.findall(r"^\|\s*★\s*\| group ", markdown, flags=re.M)
    assert len(headers) == 4
    assert markdown.count("Cheapest at each error level") == 4
    for scene, points in scenes.items():
        assert len(points) == len(TINY["speed_error_configs"][scene])
        for point in points:
            assert all(math.isfinite(value) for value in point.figures()), (scene, point)
        # "cheapest": exactly one batched point per front, and it is on the front.
        batched = [p for p in points if p.batch]
        assert len(batched) == 1 and batched[0].on_front and batched[0].batch == 8
        assert batched[0].body_steps_per_s > 0


def test_tiny_run_errors_match_known_accuracy(tiny):
    """Loose bounds from the closed forms: RK4 at h = 1/60 places the first flip within 1 ms
    (measured 1.3e-5 s in float32); the 2 ms penalty runs are within a few per cent."""
    scenes = tiny[1]["scenes"]
    by_group = {p.group: p for p in scenes["tumble"]}
    assert by_group["rk4"].error < 1e-3
    assert by_group["semi_implicit/exp_map"].error > 10 * by_group["rk4"].error
    assert scenes["bounce"][0].error < 0.1
    assert scenes["slide"][0].error < 0.02
    assert scenes["roll"][0].error < 0.02


def test_png_files_are_valid_images(tiny):
    markdown, results, out_dir = tiny
    assert sorted(results["images"]) == sorted(se.SCENE_NAMES)
    for scene, path in results["images"].items():
        assert os.path.dirname(path) == out_dir
        assert f"]({os.path.basename(path)})" in markdown
        with Image.open(path) as image:
            image.verify()
        with Image.open(path) as image:
            assert image.format == "PNG" and image.size[0] > 300 and image.size[1] > 200


def _starred_labels(markdown):
    """Per table, (starred, label) of each body row in order."""
    tables, current = [], None
    for line in markdown.splitlines():
        if re.match(r"^\|\s*★\s*\| group ", line):
            current = []
            tables.append(current)
        elif current is not None and line.startswith("| :"):
            continue
        elif current is not None and line.startswith("|"):
            cells = [c.strip() for c in line.strip("|").split("|")]
            current.append((cells[0] == "★", cells[2]))
        else:
            current = None
    return tables


def test_pareto_marks_match_pareto_front(tiny):
    markdown, results, _ = tiny
    tables = _starred_labels(markdown)
    for table, (scene, points) in zip(tables, results["scenes"].items()):
        assert [label for _, label in table] == [p.label for p in points]
        assert [star for star, _ in table] == [p.on_front for p in points]
        for panel in {p.panel for p in points}:
            members = [p for p in points if p.panel == panel]
            front = pareto_front([p.cost for p in members], [p.error for p in members])
            assert [p.on_front for p in members] == front.tolist(), scene


def _point(cost, error, panel="all", label="x"):
    return se.Point(scene="bounce", config=se.penalty(1e-3), group="penalty", label=label,
                    panel=panel, error=error, run_s=cost, horizon=1.0, num_steps=1000,
                    compile_s=1.0)


def test_fronts_are_per_panel_and_levels_read_the_front():
    points = [_point(1.0, 1e-1, "a"), _point(2.0, 1e-3, "a"), _point(3.0, 1e-2, "a"),  # dominated
              _point(0.5, math.inf, "a"), _point(5.0, 1e-2, "b")]
    se.mark_fronts(points)
    assert [p.on_front for p in points] == [True, True, False, False, True]
    levels = se.cheapest_per_level(points[:4])
    assert [(level, p.cost) for level, p in levels] == [(1e-1, 1.0), (1e-2, 2.0)]
    chosen = {mode: [points.index(p) for p in se.batched_points(points, mode)]
              for mode in se.BATCH_MODES}
    assert chosen == {"all": [0, 1, 2, 3, 4], "pareto": [0, 1, 4], "cheapest": [0, 4], "none": []}


def _visible_tick_labels(axis, low, high):
    return [label.get_text() for label in axis.get_ticklabels()
            if label.get_text() and low <= label.get_position()[axis.axis_name == "y"] <= high]


def test_speed_error_plot_labels_an_axis_shorter_than_a_decade():
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from jaxrb.bench.pareto import plot_speed_vs_error

    figure = Figure()  # as plot_scene draws: no pyplot, no global backend switch
    ax = figure.add_subplot()
    plot_speed_vs_error(ax, [1.3e-4, 2.5e-4, 8.5e-4], [1e-4, 1e-2, 1e-1], ["a", "b", "c"], ["g", "g", "g"])
    FigureCanvasAgg(figure).draw()
    # costs within one decade: at least two numbers on the x axis; errors span three powers of ten
    assert len(_visible_tick_labels(ax.xaxis, *ax.get_xlim())) >= 2
    assert len(_visible_tick_labels(ax.yaxis, *ax.get_ylim())) >= 2

# --- the error metrics against exact answers ----------------------------------------------

def test_hermite_crossing_is_fourth_order_accurate():
    times = np.arange(0.25, 7.0, 0.5)
    crossings = se.hermite_crossings(times, np.sin(times), np.cos(times))
    np.testing.assert_allclose(crossings, [math.pi, 2 * math.pi], atol=5e-5)
    # Linear interpolation of the same samples is off by ~1e-2 here.
    linear = sign_changes(times, np.sin(times))
    assert np.max(np.abs(linear - [math.pi, 2 * math.pi])) > 100 * np.max(
        np.abs(crossings - [math.pi, 2 * math.pi]))


@pytest.fixture(scope="module")
def exact_tumble():
    """Body-frame ω of the tumbling body at h = 1/60 over 10 s (DOP853, tolerance 1e-12)."""
    inertia = np.array(se.TUMBLE_INERTIA)

    def euler_equations(_, omega):
        return (np.roll(inertia, -1) - np.roll(inertia, 1)) * np.roll(omega, -1) \
            * np.roll(omega, 1) / inertia

    times = np.arange(601) / 60.0
    solution = solve_ivp(euler_equations, (0.0, 10.0), np.array(se.TUMBLE_ANGVEL), method="DOP853",
                         rtol=1e-12, atol=1e-12, t_eval=times)
    return times, solution.y.T


def test_flip_error_is_zero_for_the_exact_motion_and_catches_wrong_ones(exact_tumble):
    times, omega = exact_tumble
    reference = analytic.flip_times(se.TUMBLE_INERTIA, se.TUMBLE_ANGVEL, 10.0)
    assert len(reference) == 2
    assert se.flip_time_error(times, omega, reference) < 1e-5
    # Every flip 50 ms late.
    assert se.flip_time_error(times + 0.05, omega, reference) == pytest.approx(0.05, abs=1e-5)
    # The second flip is missing when the run stops at 6 s.
    assert se.flip_time_error(times[:361], omega[:361], reference) == math.inf


def exact_bounce(times, gap, restitution, bounces=10):
    """Height of the lowest point and v_z of a ball dropped from rest ``gap`` above the ground."""
    impacts = [math.sqrt(2 * gap / G)]
    launches = [restitution * math.sqrt(2 * G * gap)]  # upward speed after each impact
    for _ in range(bounces):
        impacts.append(impacts[-1] + 2 * launches[-1] / G)
        launches.append(restitution * launches[-1])
    falling = times < impacts[0]
    index = np.clip(np.searchsorted(impacts, times, side="right") - 1, 0, None)
    tau = times - np.asarray(impacts)[index]
    launch = np.asarray(launches)[index]
    height = np.where(falling, gap - 0.5 * G * times ** 2, launch * tau - 0.5 * G * tau ** 2)
    velocity = np.where(falling, -G * times, launch - G * tau)
    return height, velocity


def test_apex_error_is_zero_for_the_exact_motion_and_catches_wrong_ones():
    times = np.arange(0.0, 2.2, 1 / 240)
    expected = analytic.bounce_apexes(0.9, 0.8, 3)
    assert se.apex_error(*exact_bounce(times, 0.9, 0.8), expected) < 1e-9
    # e = 0.7: the third apex is (0.7/0.8)^6 of the right one.
    assert se.apex_error(*exact_bounce(times, 0.9, 0.7), expected) == \
        pytest.approx(1 - (0.7 / 0.8) ** 6, rel=1e-6)
    short = times < 1.5  # apexes at 0.77, 1.39 and 1.88 s: the third is cut
    assert se.apex_error(*(a[short] for a in exact_bounce(times, 0.9, 0.8)), expected) == math.inf


def test_stopping_distance_error_is_zero_for_the_exact_motion_and_catches_wrong_ones():
    times = np.arange(0.0, 0.8, 1e-3)

    def slide(mu):
        stop = 2.0 / (mu * G)
        t = np.minimum(times, stop)
        return 2.0 * t - 0.5 * mu * G * t ** 2

    expected = analytic.slide_distance(2.0, 0.5)
    assert se.stopping_distance_error(slide(0.5), expected) < 1e-12
    assert se.stopping_distance_error(slide(0.4), expected) == pytest.approx(0.25, rel=1e-9)
    # Cut at 0.2 s, before the stop at 0.41 s: 0.30 m of 0.41 m travelled.
    assert se.stopping_distance_error(slide(0.5)[:201], expected) == pytest.approx(
        1 - (0.4 - 0.5 * 0.5 * G * 0.04) / expected, rel=1e-9)


def test_acceleration_error_is_zero_for_the_exact_motion_and_catches_wrong_ones():
    h = 1 / 240
    times = np.arange(241) * h
    expected = analytic.rolling_acceleration(math.radians(30.0), 0.4 * 0.01, 0.1)
    assert expected == pytest.approx(5 / 7 * G * 0.5)
    assert se.acceleration_error(times, 0.5 * expected * times ** 2, expected) < 1e-9
    # Symplectic Euler's exact discrete motion, ½ a h² n (n + 1): the extra linear term is
    # no error in the acceleration.
    steps = np.arange(241)
    assert se.acceleration_error(times, 0.5 * expected * h * h * steps * (steps + 1), expected) < 1e-9
    # Sliding without friction: g sin θ, 7/5 of the rolling acceleration.
    assert se.acceleration_error(times, 0.25 * G * times ** 2, expected) == pytest.approx(0.4)


@pytest.mark.parametrize("settings, field", [
    (dict(speed_error_scenes=("tumble", "spin")), "speed_error_scenes"),
    (dict(speed_error_batch_configs="some"), "speed_error_batch_configs"),
    (dict(speed_error_horizons={"tumble": 0.0, "bounce": 1.0, "slide": 1.0, "roll": 1.0}),
     "speed_error_horizons"),
    (dict(speed_error_batch=0), "speed_error_batch"),
])
def test_bad_settings_name_the_field(settings, field):
    with pytest.raises(ValueError, match=field):
        se.run(settings)


def test_best_error_per_cost_decade():
    points = [_point(2e-4, 1e-2), _point(5e-4, 1e-3), _point(3e-3, 1e-1), _point(4e-3, math.inf)]
    bands = se.best_per_cost_band(points)
    assert [(low, p.error) for low, p in bands] == [(1e-4, 1e-3), (1e-3, 1e-1)]
    assert "Best error per cost decade" in se.band_line(points, "")
