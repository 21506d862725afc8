"""Speed against error on four scenes with closed-form answers, and their Pareto fronts.

Each configuration the engine offers (integrator and orientation update,
contact model, step size, substeps, solver iterations and scheme, time of
impact, penalty friction law, float64/float32) is run on a scene whose answer
is known in closed form (:mod:`jaxrb.analytic`) and scored on two axes:

* **error** against the closed form, one scalar per scene (below);
* **cost**: seconds of wall time per simulated second at batch 1: the median
  run time (compile excluded, ``block_until_ready``; :func:`time_jitted`) of
  the jitted rollout over the scene's horizon, every state stacked, divided by
  the horizon. Beside it: the compile time, and body-steps per second of
  ``batch`` worlds (1 024 in the full report), ``jax.vmap`` of a
  ``batch_steps``-step rollout inside one jit (final state only), with its
  own compile time.

Scenes and error metrics:

* **tumble**: torque-free body, principal inertia (0.3, 0.35, 0.4) kg m²,
  ω₀ = (0.1, 15, 0.1) rad/s (the intermediate-axis flip). Error: the largest
  |t_flip − t_exact| over the flips of :func:`jaxrb.analytic.flip_times` in the
  horizon (s); inf when a flip is missing. Flips are the sign changes of the
  body-frame ω_y, located inside a step by the cubic Hermite interpolant that
  uses Euler's equation for the slope, so the sampling itself adds O(h⁴), far
  below any integrator's error (linear interpolation would add ~h²).
* **bounce**: sphere r = 0.1 m, 1 kg, dropped from 1 m (0.9 m gap) onto a
  plane, restitution 0.8. Error: the largest relative error of the first three
  apex heights against :func:`jaxrb.analytic.bounce_apexes`; each apex is read
  from the last rising sample as z + v_z²/2g (exact in free flight, so
  sampling adds nothing); inf when fewer than three apexes occur.
* **slide**: box (half 0.1 m, 1 kg) at v₀ = 2 m/s on a plane, μ = 0.5. Error:
  |d − d_exact| / d_exact with d the displacement at the end of the horizon
  (after the stop) and d_exact = v₀²/(2μg) (:func:`jaxrb.analytic.slide_distance`).
* **roll**: sphere r = 0.1 m, 1 kg, released at rest on a plane tilted 30°
  (tilted normal, μ = 1, well above the 2/7·tan θ = 0.165 rolling needs).
  Error: |a − a_exact| / a_exact with a twice the leading coefficient of a
  least-squares quadratic fit of the downhill distance over t ≥ 0.2 s (after
  the contact settles) and a_exact = 5/7·g·sin θ
  (:func:`jaxrb.analytic.rolling_acceleration`).

Every configuration is a plain dict; :data:`QUICK` and :data:`FULL` hold the
grids. :func:`speed_error_section` runs them and returns Markdown (one table
per scene, Pareto points marked ★, a "cheapest at each error level" line) and
writes one PNG per scene (error against cost, log-log, Pareto front joined;
:func:`jaxrb.bench.pareto.plot_speed_vs_error`).
"""

from __future__ import annotations

import dataclasses
import math
import os
from typing import Callable, Optional, Sequence

import jax
import jax.numpy as jnp
import numpy as np

import jaxrb as rb
from jaxrb import analytic
from jaxrb import quaternion as quat_ops
from jaxrb.bench.free_body import (TUMBLE_ANGVEL, TUMBLE_INERTIA, TUMBLE_CONFIGS, compare_flips,
                                   tumble_scene)
from jaxrb.bench.pareto import pareto_front, plot_speed_vs_error
from jaxrb.bench.report import fmt_fixed, fmt_sci, fmt_si, fmt_step, markdown_table
from jaxrb.bench.timing import Stopwatch, compile_jitted, final_state_fn, time_compiled, time_jitted
from jaxrb.options import grouped

GRAVITY = 9.81
RADIUS = 0.1  # m, the bouncing and rolling spheres
HALF = 0.1  # m, half-extent of the sliding box
DROP = 1.0  # m, initial centre height of the bouncing sphere
RESTITUTION = 0.8
NUM_APEXES = 3
SLIDE_SPEED, SLIDE_FRICTION = 2.0, 0.5
SLOPE = math.radians(30.0)
ROLL_FRICTION = 1.0
ROLL_SETTLE = 0.2  # s; the fit of the rolling distance starts here

SCENE_NAMES = ("tumble", "bounce", "slide", "roll")
BATCH_MODES = ("all", "pareto", "cheapest", "none")


# --- error metrics (host NumPy, independent of the engine) ---------------------------------

def hermite_crossings(times, values, slopes) -> np.ndarray:
    """Times where ``values`` changes sign, located on the cubic Hermite interpolant.

    Args:
        times: (m,) increasing sample times (s).
        values: (m,) samples of a smooth function.
        slopes: (m,) its time derivative at the samples.

    Returns:
        (k,) crossing times, increasing; the root of the cubic through both
        ends of each sign-changing interval (bisection to rounding). A
        non-finite sample ends the search.
    """
    times, values, slopes = (np.asarray(a, dtype=np.float64) for a in (times, values, slopes))
    finite = np.isfinite(values) & np.isfinite(slopes)
    if not finite.all():
        cut = int(np.argmin(finite))
        times, values, slopes = times[:cut], values[:cut], slopes[:cut]
    positive = values > 0.0
    index = np.nonzero(positive[:-1] != positive[1:])[0]
    t0, width = times[index], times[index + 1] - times[index]
    v0, v1 = values[index], values[index + 1]
    m0, m1 = slopes[index] * width, slopes[index + 1] * width

    def cubic(s):
        s2, s3 = s * s, s * s * s
        return ((2 * s3 - 3 * s2 + 1) * v0 + (s3 - 2 * s2 + s) * m0
                + (-2 * s3 + 3 * s2) * v1 + (s3 - s2) * m1)

    # Bisection keeps the root inside the interval even where the cubic has
    # three roots there (then it finds one of them, like the sign change does).
    low, high = np.zeros_like(t0), np.ones_like(t0)
    start_sign = np.sign(v0)
    for _ in range(60):
        middle = 0.5 * (low + high)
        same = np.sign(cubic(middle)) == start_sign
        low, high = np.where(same, middle, low), np.where(same, high, middle)
    return t0 + 0.5 * (low + high) * width


def flip_time_error(times, body_angvel, reference, inertia=TUMBLE_INERTIA) -> float:
    """Largest flip-time error of a tumbling run against the exact flip times.

    Args:
        times: (m,) sample times (s), increasing.
        body_angvel: (m, 3) body-frame angular velocity at those times (rad/s).
        reference: (k,) exact flip times (s), e.g. from :func:`jaxrb.analytic.flip_times`.
        inertia: (3,) principal moments (kg m²) of the body; the middle one is axis 1 (y).

    Returns:
        max_i |t_i − t_ref,i| over the reference flips (s); inf when the run has
        fewer flips than the reference, 0 when the reference has none.
    """
    body_angvel = np.asarray(body_angvel, dtype=np.float64)
    if body_angvel.ndim != 2 or body_angvel.shape[1] != 3:
        raise ValueError(f"flip_time_error: 'body_angvel' must have shape (m, 3), got "
                         f"{body_angvel.shape}")
    i1, i2, i3 = (float(v) for v in inertia)
    # Euler's equation for the middle axis gives the slope of ω_y at every sample.
    slope = (i3 - i1) / i2 * body_angvel[:, 2] * body_angvel[:, 0]
    flips = hermite_crossings(times, body_angvel[:, 1], slope)
    return float(compare_flips(flips, np.asarray(reference, dtype=np.float64)).max_error)


def apex_heights(height, vertical_velocity, gravity: float = GRAVITY) -> np.ndarray:
    """Apex heights of a bouncing body, one per change of v_z from up to down.

    Args:
        height: (m,) height of the lowest point above the ground at each sample (m).
        vertical_velocity: (m,) v_z at each sample (m/s).
        gravity: scalar |g| (m/s²).

    Returns:
        (k,) apex heights (m): z + v_z²/(2g) at the last sample with v_z > 0
        before one with v_z ≤ 0, the top of the free-flight parabola through
        that sample.
    """
    height = np.asarray(height, dtype=np.float64)
    vz = np.asarray(vertical_velocity, dtype=np.float64)
    rising = np.nonzero((vz[:-1] > 0.0) & (vz[1:] <= 0.0))[0]
    return height[rising] + vz[rising] ** 2 / (2.0 * gravity)


def apex_error(height, vertical_velocity, expected, gravity: float = GRAVITY) -> float:
    """Largest relative error of the first apex heights against the closed form.

    Args:
        height: (m,) height of the lowest point above the ground (m).
        vertical_velocity: (m,) v_z (m/s).
        expected: (k,) exact apex heights (m), e.g. :func:`jaxrb.analytic.bounce_apexes`.
        gravity: scalar |g| (m/s²).

    Returns:
        max_i |h_i − h_exact,i| / h_exact,i over the first k apexes; inf when
        fewer than k apexes occur or a sample is non-finite.
    """
    expected = np.asarray(expected, dtype=np.float64)
    if not (np.all(np.isfinite(height)) and np.all(np.isfinite(vertical_velocity))):
        return math.inf
    heights = apex_heights(height, vertical_velocity, gravity)
    if len(heights) < len(expected):
        return math.inf
    return float(np.max(np.abs(heights[:len(expected)] - expected) / expected))


def stopping_distance_error(displacement, expected: float) -> float:
    """Relative error of a sliding body's stopping distance.

    Args:
        displacement: (m,) distance travelled along the initial velocity at each
            sample (m); the last sample is taken as the stopping distance (the
            horizon must reach past the stop).
        expected: scalar exact stopping distance (m), e.g. :func:`jaxrb.analytic.slide_distance`.

    Returns:
        |d_last − expected| / expected; inf when a sample is non-finite.
    """
    displacement = np.asarray(displacement, dtype=np.float64)
    if not np.all(np.isfinite(displacement)):
        return math.inf
    return float(abs(displacement[-1] - expected) / expected)


def acceleration_error(times, distance, expected: float, settle: float = ROLL_SETTLE) -> float:
    """Relative error of a constant acceleration measured from a trajectory.

    Args:
        times: (m,) sample times (s).
        distance: (m,) distance travelled along the acceleration (m).
        expected: scalar exact acceleration (m/s²), e.g. :func:`jaxrb.analytic.rolling_acceleration`.
        settle: samples before this time (s) are left out of the fit.

    Returns:
        |a − expected| / |expected| with a twice the leading coefficient of a
        least-squares quadratic in t fitted over t ≥ settle; inf when a sample
        is non-finite or fewer than 3 samples remain.
    """
    times = np.asarray(times, dtype=np.float64)
    distance = np.asarray(distance, dtype=np.float64)
    late = times >= settle
    if late.sum() < 3 or not np.all(np.isfinite(distance[late])):
        return math.inf
    acceleration = 2.0 * np.polyfit(times[late], distance[late], 2)[0]
    return float(abs(acceleration - expected) / abs(expected))


# --- scenes ----------------------------------------------------------------------------------

def bounce_scene():
    """The bouncing sphere (r = 0.1 m, 1 kg, centre at 1 m, e = 0.8 on both) over a plane.

    Returns:
        An unbuilt :class:`jaxrb.Scene`.
    """
    scene = rb.Scene(dim=3)
    scene.add_plane(restitution=RESTITUTION)
    scene.add_body(rb.Sphere(RADIUS), mass=1.0, pos=(0.0, 0.0, DROP), restitution=RESTITUTION)
    return scene


def slide_scene():
    """The sliding box (half 0.1 m, 1 kg, v₀ = 2 m/s along x, μ = 0.5 on both) on a plane.

    Returns:
        An unbuilt :class:`jaxrb.Scene`.
    """
    scene = rb.Scene(dim=3)
    scene.add_plane(friction=SLIDE_FRICTION)
    scene.add_body(rb.Box((HALF,) * 3), mass=1.0, pos=(0.0, 0.0, HALF), vel=(SLIDE_SPEED, 0.0, 0.0),
                   friction=SLIDE_FRICTION)
    return scene


#: unit normal of the slope and the downhill direction (the plane descends towards +x)
SLOPE_NORMAL = np.array([math.sin(SLOPE), 0.0, math.cos(SLOPE)])
DOWNHILL = np.array([math.cos(SLOPE), 0.0, -math.sin(SLOPE)])


def roll_scene():
    """The sphere (r = 0.1 m, 1 kg, at rest, μ = 1) touching a plane tilted 30° about y.

    Returns:
        An unbuilt :class:`jaxrb.Scene`.
    """
    scene = rb.Scene(dim=3)
    scene.add_plane(normal=SLOPE_NORMAL, friction=ROLL_FRICTION)
    scene.add_body(rb.Sphere(RADIUS), mass=1.0, pos=RADIUS * SLOPE_NORMAL, friction=ROLL_FRICTION)
    return scene


def exact_answers(tumble_horizon: float) -> dict:
    """The closed-form value each scene's error is measured against.

    Args:
        tumble_horizon: scalar horizon of the tumbling run (s).

    Returns:
        {"tumble": (k,) flip times (s), "bounce": (3,) apex heights (m),
        "slide": stopping distance (m), "roll": acceleration (m/s²)}.
    """
    return {
        "tumble": analytic.flip_times(TUMBLE_INERTIA, TUMBLE_ANGVEL, tumble_horizon),
        "bounce": analytic.bounce_apexes(DROP - RADIUS, RESTITUTION, NUM_APEXES),
        "slide": analytic.slide_distance(SLIDE_SPEED, SLIDE_FRICTION, GRAVITY),
        "roll": analytic.rolling_acceleration(SLOPE, 0.4 * RADIUS ** 2, RADIUS, GRAVITY),
    }


# --- configuration grids --------------------------------------------------------------------

def tumble_grid(steps: Sequence[float], dtypes: Sequence[str] = ("float64", "float32"),
                configs: Sequence[tuple] = TUMBLE_CONFIGS) -> list:
    """Every (integrator, orientation) pair × step × dtype, as configuration dicts.

    Args:
        steps: (s,) step sizes (s).
        dtypes: dtype names.
        configs: (integrator, orientation or None) pairs; default all seven.

    Returns:
        A list of dicts with keys integrator, orientation, dt, dtype.
    """
    return [dict(integrator=integrator, orientation=orientation, dt=float(h), dtype=dtype)
            for dtype in dtypes for integrator, orientation in configs for h in steps]


def impulse(dt, substeps=4, iterations=4, time_of_impact=False, solver="sequential",
            integrator="semi_implicit", dtype="float32") -> dict:
    """One impulse-contact configuration.

    Args:
        dt: scalar step of one ``step`` call (s).
        substeps: substeps per step.
        iterations: impulse iterations per substep.
        time_of_impact: resolve sphere–plane impacts at their time inside the substep.
        solver: ``"sequential"`` or ``"jacobi"``.
        integrator: ``"semi_implicit"`` or ``"implicit_gyro"``.
        dtype: dtype name.

    Returns:
        The configuration dict (the build options it sets, and its dtype).
    """
    return dict(contact="impulse", dt=float(dt), substeps=substeps, iterations=iterations,
                time_of_impact=time_of_impact, solver=solver, integrator=integrator, dtype=dtype)


def penalty(dt, friction="spring", smooth=False, integrator="semi_implicit",
            dtype="float32") -> dict:
    """One penalty-contact configuration (one substep; the default spring of 0.03/h Hz).

    Args:
        dt: scalar step (s).
        friction: penalty friction law, ``"spring"`` or ``"regularized"``.
        smooth: use the softplus activation (width 1 mm).
        integrator: ``"semi_implicit"`` or ``"implicit_gyro"``.
        dtype: dtype name.

    Returns:
        The configuration dict.
    """
    return dict(contact="penalty", dt=float(dt), substeps=1, penalty_friction=friction,
                smooth=smooth, integrator=integrator, dtype=dtype)


IMPULSE_STEPS = (1 / 60, 1 / 120, 1 / 240)
PENALTY_STEPS = (2e-3, 1e-3, 5e-4)


def bounce_grid_full() -> list:
    """Bounce: dt × substeps (1, 2, 4, 8); time of impact at substeps 1 and 4; iterations 2
    and 8 and the Jacobi solver at one setting; penalty at three steps and with the smooth
    activation. Iterations barely matter for one sphere, so they are not crossed with the rest.

    Returns:
        A list of configuration dicts.
    """
    grid = [impulse(dt, substeps) for substeps in (1, 2, 4, 8) for dt in IMPULSE_STEPS]
    grid += [impulse(dt, substeps, time_of_impact=True) for substeps in (1, 4) for dt in IMPULSE_STEPS]
    grid += [impulse(1 / 120, 4, iterations=2), impulse(1 / 120, 4, iterations=8),
             impulse(1 / 120, 4, solver="jacobi")]
    grid += [penalty(dt) for dt in PENALTY_STEPS] + [penalty(1e-3, smooth=True)]
    return grid


def slide_grid_full() -> list:
    """Slide: impulse dt × substeps (1, 4) plus iterations 2/8 and Jacobi at 1/60 × 4;
    penalty at three steps with the spring friction law and one with the regularised law.

    Returns:
        A list of configuration dicts.
    """
    grid = [impulse(dt, substeps) for substeps in (1, 4) for dt in IMPULSE_STEPS]
    grid += [impulse(1 / 60, 4, iterations=2), impulse(1 / 60, 4, iterations=8),
             impulse(1 / 60, 4, solver="jacobi"), impulse(1 / 60, 4, time_of_impact=True)]
    grid += [penalty(dt) for dt in PENALTY_STEPS] + [penalty(1e-3, friction="regularized")]
    return grid


def roll_grid_full() -> list:
    """Roll: impulse dt × substeps (1, 4), iterations 2, Jacobi and the implicit gyroscopic
    integrator at 1/60 × 4; penalty at three steps and with the regularised friction law.

    Returns:
        A list of configuration dicts.
    """
    grid = [impulse(dt, substeps) for substeps in (1, 4) for dt in IMPULSE_STEPS]
    grid += [impulse(1 / 60, 4, iterations=2), impulse(1 / 60, 4, solver="jacobi"),
             impulse(1 / 60, 4, integrator="implicit_gyro")]
    grid += [penalty(dt) for dt in PENALTY_STEPS] + [penalty(1e-3, friction="regularized")]
    return grid


#: Settings of the committed report: the grids above, 1 024 worlds.
FULL = dict(
    speed_error_scenes=SCENE_NAMES,
    speed_error_configs={
        "tumble": tumble_grid((1 / 60, 1 / 120, 1 / 240, 1 / 480, 1 / 1000)),
        "bounce": bounce_grid_full(),
        "slide": slide_grid_full(),
        "roll": roll_grid_full(),
    },
    speed_error_horizons={"tumble": 20.0, "bounce": 2.2, "slide": 0.8, "roll": 1.0},
    speed_error_batch=1024, speed_error_batch_steps=100, speed_error_batch_configs="all",
    speed_error_repeats=5,
)

#: A run of about 25 s on 2 cores: one configuration a scene (the flip's is the
#: float32 target's integrator; the peers section runs it in float64 too) and its
#: batched throughput. Compiles dominate the time, and impulse contact's most (the
#: bounce's compiled for 11 s, the roll's for 13 s at batch 1 and 1 024), so quick's
#: contact scenes run penalty contact only; the contact section shows impulse
#: contact's cost.
QUICK = dict(
    speed_error_scenes=SCENE_NAMES,
    speed_error_configs={
        "tumble": tumble_grid((1 / 60,), ("float32",), (("rk4_body", None),)),
        "bounce": [penalty(1e-3)],
        "slide": [penalty(2e-3)],
        "roll": [penalty(2e-3)],
    },
    speed_error_horizons={"tumble": 5.0, "bounce": 2.2, "slide": 0.6, "roll": 0.6},
    speed_error_batch=1024, speed_error_batch_steps=50, speed_error_batch_configs="cheapest",
    speed_error_repeats=3,
)


# --- running one configuration ---------------------------------------------------------------

@dataclasses.dataclass
class Point:
    """One configuration of one scene: its error and its costs.

    Attributes:
        scene: scene name, one of :data:`SCENE_NAMES`.
        config: the configuration dict (build options).
        group: legend group (integrator/orientation, or contact model and substeps).
        label: short text beside the point (step size and anything unusual).
        panel: which plot panel and Pareto front it belongs to (the dtype for
            the tumbling scene, else ``"all"``).
        error: scalar error against the closed form (inf: failed).
        run_s: median wall seconds of the batch-1 rollout over the horizon.
        horizon: simulated seconds of that rollout.
        num_steps: steps in it.
        compile_s: compile seconds of the batch-1 rollout.
        batch: worlds of the batched run (0: not run).
        batch_steps: steps of the batched run.
        batch_run_s: median wall seconds of the batched run (nan: not run).
        batch_compile_s: its compile seconds (nan: not run).
        on_front: on the Pareto front of its panel (set after all points ran).
    """

    scene: str
    config: dict
    group: str
    label: str
    panel: str
    error: float
    run_s: float
    horizon: float
    num_steps: int
    compile_s: float
    batch: int = 0
    batch_steps: int = 0
    batch_run_s: float = math.nan
    batch_compile_s: float = math.nan
    on_front: bool = False

    @property
    def cost(self) -> float:
        """Wall seconds per simulated second at batch 1.

        Returns:
            run_s / horizon.
        """
        return self.run_s / self.horizon

    @property
    def step_us(self) -> float:
        """Wall microseconds per step at batch 1.

        Returns:
            1e6 · run_s / num_steps.
        """
        return 1e6 * self.run_s / self.num_steps

    @property
    def body_steps_per_s(self) -> float:
        """Body-steps per second of the batched run (every scene here has one body).

        Returns:
            batch · batch_steps / batch_run_s, or nan when not run.
        """
        return self.batch * self.batch_steps / self.batch_run_s if self.batch else math.nan

    def figures(self) -> list:
        """Every measured number of the point (for finiteness checks).

        Returns:
            A list of floats: error, cost, µs/step, compile s, and the batched
            run s, compile s and body-steps/s when the batched run was made.
        """
        values = [self.error, self.cost, self.step_us, self.compile_s]
        if self.batch:
            values += [self.batch_run_s, self.batch_compile_s, self.body_steps_per_s]
        return values


def describe(scene: str, config: dict) -> tuple:
    """How a configuration is shown.

    Args:
        scene: one of :data:`SCENE_NAMES`.
        config: a configuration dict.

    Returns:
        ``(group, label, panel)``: legend group, text beside the point, plot panel.
    """
    if scene == "tumble":
        group = config["integrator"] + (f"/{config['orientation']}" if config["orientation"] else "")
        return group, fmt_step(config["dt"]), config["dtype"]
    extras = []
    if config["contact"] == "impulse":
        group = f"impulse ×{config['substeps']}" + (" toi" if config["time_of_impact"] else "")
        if config["iterations"] != 4:
            extras.append(f"it{config['iterations']}")
        if config["solver"] != "sequential":
            extras.append(config["solver"])
    else:
        group = "penalty"
        if config["penalty_friction"] != "spring":
            extras.append(config["penalty_friction"])
        if config["smooth"]:
            extras.append("smooth")
    if config["integrator"] != "semi_implicit":
        extras.append(config["integrator"])
    if config["dtype"] != "float32":
        extras.append(config["dtype"])
    return group, " ".join([fmt_step(config["dt"])] + extras), "all"


def config_text(scene: str, config: dict) -> str:
    """The configuration in words, for the tables.

    Args:
        scene: one of :data:`SCENE_NAMES`.
        config: a configuration dict.

    Returns:
        Every option it sets, comma-separated.
    """
    if scene == "tumble":
        return f"{config['integrator']}, {config['orientation'] or '—'}, {config['dtype']}"
    if config["contact"] == "impulse":
        text = (f"impulse ×{config['substeps']} substeps, {config['iterations']} it, "
                f"{config['solver']}" + (", toi" if config["time_of_impact"] else ""))
    else:
        text = (f"penalty, {config['penalty_friction']} friction"
                + (", smooth" if config["smooth"] else ""))
    if config["integrator"] != "semi_implicit":
        text += f", {config['integrator']}"
    return text + ("" if config["dtype"] == "float32" else f", {config['dtype']}")


def build(scene: str, config: dict):
    """``(model, params, state)`` of one scene under one configuration.

    Args:
        scene: one of :data:`SCENE_NAMES`.
        config: a configuration dict (see :func:`tumble_grid`, :func:`impulse`, :func:`penalty`).

    Returns:
        What :meth:`jaxrb.Scene.build` returns.
    """
    dtype = jnp.dtype(config["dtype"])
    if scene == "tumble":
        return tumble_scene().build(dt=config["dt"], integrator=config["integrator"],
                                    orientation=config["orientation"], dtype=dtype)
    factories = {"bounce": bounce_scene, "slide": slide_scene, "roll": roll_scene}
    if scene not in factories:
        raise ValueError(f"speed_error: unknown scene {scene!r}; valid: {', '.join(SCENE_NAMES)}")
    options = dict(dt=config["dt"], integrator=config["integrator"], contact=config["contact"],
                   substeps=config["substeps"], dtype=dtype)
    if config["contact"] == "impulse":
        options.update(iterations=config["iterations"], solver=config["solver"],
                       time_of_impact=config["time_of_impact"])
    else:
        options.update(penalty_friction=config["penalty_friction"])
        if config["smooth"]:
            options.update(penalty_width=1e-3)
    return factories[scene]().build(**grouped(options))


def trajectory_error(scene: str, traj, state0, h: float, exact) -> float:
    """Error of one rollout against the scene's closed form.

    Args:
        scene: one of :data:`SCENE_NAMES`.
        traj: stacked States from :func:`jaxrb.rollout` (the states after steps 1..m).
        state0: the initial State (prepended: the metrics see t = 0 too).
        h: the step (s); sample k is at t = k·h exactly (``state.time``
            accumulates rounding in float32).
        exact: the scene's entry of :func:`exact_answers`.

    Returns:
        The scene's scalar error (see the module docstring).
    """
    def series(field):
        first = np.asarray(getattr(state0, field), dtype=np.float64)[None, 0]
        return np.concatenate([first, np.asarray(getattr(traj, field), dtype=np.float64)[:, 0]])

    pos, vel = series("pos"), series("vel")
    times = np.arange(len(pos)) * h
    if scene == "tumble":
        quat, angvel = series("quat"), series("angvel")
        body_angvel = np.asarray(quat_ops.rotate_inverse(jnp.asarray(quat), jnp.asarray(angvel)))
        return flip_time_error(times, body_angvel, exact)
    if scene == "bounce":
        return apex_error(pos[:, 2] - RADIUS, vel[:, 2], exact)
    if scene == "slide":
        return stopping_distance_error(pos[:, 0] - pos[0, 0], exact)
    if scene == "roll":
        return acceleration_error(times, (pos - pos[0]) @ DOWNHILL, exact)
    raise ValueError(f"speed_error: unknown scene {scene!r}; valid: {', '.join(SCENE_NAMES)}")


def _tiled_worlds(state, batch: int, seed: int = 0):
    """``batch`` copies of ``state``, each lifted by 0–1 mm and its spin nudged by ≤ 1e-3 rad/s,
    so no two worlds are the same (the physics is unchanged to that size)."""
    rng = np.random.default_rng(seed)
    tiled = jax.tree_util.tree_map(lambda a: jnp.broadcast_to(a, (batch,) + a.shape), state)
    dtype = state.pos.dtype
    lift = np.zeros((batch,) + state.pos.shape)
    lift[..., -1] = rng.uniform(0.0, 1e-3, size=(batch, state.pos.shape[0]))
    nudge = rng.uniform(-1e-3, 1e-3, size=(batch,) + state.angvel.shape)
    return tiled.replace(pos=tiled.pos + jnp.asarray(lift, dtype),
                         angvel=tiled.angvel + jnp.asarray(nudge, dtype))


def run_point(scene: str, config: dict, horizon: float, exact, repeats: int = 5) -> Point:
    """Roll one configuration out over ``horizon`` at batch 1, time it and score it.

    Args:
        scene: one of :data:`SCENE_NAMES`.
        config: a configuration dict.
        horizon: simulated seconds (rounded to whole steps).
        exact: the scene's entry of :func:`exact_answers`.
        repeats: timed calls at most (median reported).

    Returns:
        A :class:`Point` without the batched figures (see :func:`time_batched`).
    """
    model, params, state = build(scene, config)
    step = rb.make_step(model)
    num_steps = max(1, int(round(horizon / config["dt"])))

    def trajectory(state0, params0):
        return rb.rollout(step, state0, params0, num_steps)

    timing = time_jitted(trajectory, state, params, repeats=repeats, budget_s=3.0)
    error = trajectory_error(scene, timing.output, state, config["dt"], exact)
    group, label, panel = describe(scene, config)
    return Point(scene=scene, config=dict(config), group=group, label=label, panel=panel,
                 error=error, run_s=timing.run_s, horizon=num_steps * config["dt"],
                 num_steps=num_steps, compile_s=timing.compile_s)


def time_batched(result: Point, batch: int, num_steps: int, repeats: int = 5,
                 cache: Optional[dict] = None) -> Point:
    """Add body-steps/s of ``batch`` vmapped worlds to ``point`` (in place).

    Args:
        result: a :class:`Point` from :func:`run_point`.
        batch: number of worlds.
        num_steps: steps scanned inside one jit (final state only).
        repeats: timed calls at most.
        cache: optional dict of compiled functions, filled here. ``dt`` is a
            Param, so configurations that differ only in their step share one
            Model and one compiled function; its compile time is reported for
            each of them.

    Returns:
        ``result``, with batch, batch_steps, batch_run_s and batch_compile_s set.
    """
    point = result
    model, params, state = build(point.scene, point.config)
    states = _tiled_worlds(state, batch)
    key = (point.scene, model, point.config["dtype"], batch, num_steps)
    if cache is None or key not in cache:
        compiled = compile_jitted(final_state_fn(rb.make_step(model), num_steps, batched=True),
                                  states, params)
        if cache is not None:
            cache[key] = compiled
    else:
        compiled = cache[key]
    run_s, _, output = time_compiled(compiled[0], states, params, repeats=repeats, budget_s=5.0)
    if not bool(jnp.all(jnp.isfinite(output.pos))):
        raise FloatingPointError(f"speed_error: batched {point.scene} {point.label} went non-finite")
    point.batch, point.batch_steps = batch, num_steps
    point.batch_run_s, point.batch_compile_s = run_s, compiled[1]
    return point


def batched_points(points: Sequence[Point], mode: str) -> list:
    """Which points get a batched run.

    Args:
        points: (k,) list of :class:`Point`, fronts marked.
        mode: ``"all"``, ``"pareto"`` (the front of each panel), ``"cheapest"``
            (the cheapest front point of each panel) or ``"none"``.

    Returns:
        The chosen points, in order.
    """
    if mode == "all":
        return list(points)
    if mode == "none":
        return []
    chosen = []
    for panel in dict.fromkeys(p.panel for p in points):
        front = [p for p in points if p.panel == panel and p.on_front]
        chosen += front if mode == "pareto" else sorted(front, key=lambda p: p.cost)[:1]
    return chosen


def mark_fronts(points: Sequence[Point]) -> None:
    """Set ``on_front`` of every point: the Pareto front (cost, error) within its panel.

    Args:
        points: (k,) list of :class:`Point`; changed in place.
    """
    for panel in dict.fromkeys(p.panel for p in points):
        members = [p for p in points if p.panel == panel]
        front = pareto_front([p.cost for p in members], [p.error for p in members])
        for point, flag in zip(members, front):
            point.on_front = bool(flag)


# --- settings, the run, the report ----------------------------------------------------------

def _check_settings(settings: dict) -> dict:
    """Fill defaults from :data:`QUICK` and reject malformed settings naming the field."""
    merged = {**QUICK, **{k: v for k, v in settings.items() if k.startswith("speed_error_")}}
    for key in ("out_dir", "repeats"):
        if key in settings and f"speed_error_{key}" not in settings:
            merged[f"speed_error_{key}"] = settings[key]
    scenes = merged["speed_error_scenes"]
    for name in scenes:
        if name not in SCENE_NAMES:
            raise ValueError(f"speed_error: 'speed_error_scenes' has unknown scene {name!r}; "
                             f"valid: {', '.join(SCENE_NAMES)}")
        if not merged["speed_error_configs"].get(name):
            raise ValueError(f"speed_error: 'speed_error_configs' has no configurations for {name!r}")
        horizon = merged["speed_error_horizons"].get(name)
        if horizon is None or not horizon > 0:
            raise ValueError(f"speed_error: 'speed_error_horizons' needs a positive horizon for "
                             f"{name!r}, got {horizon!r}")
    if merged["speed_error_batch_configs"] not in BATCH_MODES:
        raise ValueError(f"speed_error: 'speed_error_batch_configs' must be one of {BATCH_MODES}, "
                         f"got {merged['speed_error_batch_configs']!r}")
    for key in ("speed_error_batch", "speed_error_batch_steps", "speed_error_repeats"):
        if not (isinstance(merged[key], int) and merged[key] >= 1):
            raise ValueError(f"speed_error: {key!r} must be an integer >= 1, got {merged[key]!r}")
    return merged


def run(settings: dict, log: Optional[Callable] = None) -> dict:
    """Run every configuration of every scene in ``settings``.

    Args:
        settings: keys ``speed_error_*`` as in :data:`QUICK` (missing ones
            are taken from it); ``repeats`` is used when
            ``speed_error_repeats`` is absent.
        log: optional progress callback taking one string.

    Returns:
        {scene: list of :class:`Point`}, fronts marked, in configuration order.
    """
    if not jax.config.jax_enable_x64:
        raise RuntimeError("speed_error: needs jax_enable_x64 (the float64 tumbling runs)")
    settings = _check_settings(settings)
    log = log or (lambda text: None)
    exact = exact_answers(settings["speed_error_horizons"]["tumble"])
    repeats = settings["speed_error_repeats"]
    results = {}
    cache = {}
    for scene in settings["speed_error_scenes"]:
        horizon = settings["speed_error_horizons"][scene]
        points = []
        for config in settings["speed_error_configs"][scene]:
            point = run_point(scene, config, horizon, exact[scene], repeats)
            log(f"speed/error {scene:>6} {point.group:>22} {point.label:>16} {point.panel:>7}: "
                f"error {fmt_sci(point.error)}, {fmt_sci(point.cost)} s/s, compile "
                f"{point.compile_s:.2f} s")
            points.append(point)
        mark_fronts(points)
        for point in batched_points(points, settings["speed_error_batch_configs"]):
            time_batched(point, settings["speed_error_batch"], settings["speed_error_batch_steps"],
                         repeats, cache)
            log(f"speed/error {scene:>6} {point.group:>22} {point.label:>16} {point.panel:>7}: "
                f"batch {point.batch}: {fmt_si(point.body_steps_per_s, ' body-steps/s')}, "
                f"compile {point.batch_compile_s:.2f} s")
        results[scene] = points
    return results


def cheapest_per_level(points: Sequence[Point]) -> list:
    """The cheapest point reaching each decade of error, from the worst finite error down.

    Args:
        points: (k,) list of :class:`Point` of one panel.

    Returns:
        [(level, point)] for levels 10^k from above the largest finite error
        down to the smallest error reached; ``point`` is the cheapest with
        error ≤ level (always on the Pareto front).
    """
    finite = [p for p in points if math.isfinite(p.error) and math.isfinite(p.cost)]
    positive = [p.error for p in finite if p.error > 0]
    if not positive:
        return []
    top = math.ceil(math.log10(max(positive)))
    bottom = math.floor(math.log10(min(positive)))
    levels = []
    for exponent in range(top, bottom - 1, -1):
        level = 10.0 ** exponent
        reaching = [p for p in finite if p.error <= level]
        if reaching:
            best = min(reaching, key=lambda p: (p.cost, p.error))
            if not levels or best is not levels[-1][1]:
                levels.append((level, best))
    return levels


def best_per_cost_band(points: Sequence[Point]) -> list:
    """The most accurate point within each decade of cost.

    Args:
        points: (k,) list of :class:`Point` of one panel.

    Returns:
        [(low, point)] for each decade [low, 10·low) of s / sim s that holds a
        point with a finite error, cheapest decade first; ``point`` has the
        smallest error in that decade (ties: the cheaper).
    """
    finite = [p for p in points if math.isfinite(p.error) and math.isfinite(p.cost) and p.cost > 0]
    bands = {}
    for point in finite:
        low = 10.0 ** math.floor(math.log10(point.cost))
        best = bands.get(low)
        if best is None or (point.error, point.cost) < (best.error, best.cost):
            bands[low] = point
    return sorted(bands.items())


def band_line(points: Sequence[Point], unit: str) -> str:
    """One line: the best error in each decade of cost.

    Args:
        points: (k,) list of :class:`Point` of one panel.
        unit: text after each error (e.g. ``" s"``).

    Returns:
        The line, or ``""`` when no point has a finite error.
    """
    bands = best_per_cost_band(points)
    if not bands:
        return ""
    parts = [f"[{fmt_sci(low, 0)}, {fmt_sci(10 * low, 0)}) s/s: {fmt_sci(p.error)}{unit} "
             f"({p.group} {p.label})" for low, p in bands]
    return "Best error per cost decade — " + "; ".join(parts) + "."


def summary_line(points: Sequence[Point], unit: str) -> str:
    """One line: the cheapest configuration at each error level.

    Args:
        points: (k,) list of :class:`Point` of one panel.
        unit: text after each level (e.g. ``" s"``).

    Returns:
        The line.
    """
    levels = cheapest_per_level(points)
    if not levels:
        return "No configuration reached a finite error."
    parts = [f"≤ {fmt_sci(level, 0)}{unit}: {p.group} {p.label} (error {fmt_sci(p.error)}, "
             f"{fmt_sci(p.cost)} s/s)"
             for level, p in levels]
    return "Cheapest at each error level — " + "; ".join(parts) + "."


SCENE_TEXT = {
    "tumble": ("Torque-free tumbling (intermediate-axis flip)", "max flip-time error", " s",
               "Body with principal inertia (0.3, 0.35, 0.4) kg m², ω₀ = (0.1, 15, 0.1) rad/s "
               "(body frame), no gravity. Error: max |t_flip − t_exact| over the flips of "
               "`analytic.flip_times` (Jacobi elliptic solution) in the horizon, flips located by "
               "cubic Hermite interpolation of the body-frame ω_y (slope from Euler's equation); "
               "inf when a flip is missing. One Pareto front per dtype."),
    "bounce": ("Bouncing sphere (restitution 0.8)", "max rel. error of 3 apexes", "",
               "Sphere r = 0.1 m, 1 kg, dropped from 1 m onto a plane, e = 0.8, semi-implicit "
               "Euler. Error: max relative error of the first three apex heights (read as "
               "z + v_z²/2g at the last rising sample) against `analytic.bounce_apexes`."),
    "slide": ("Sliding box (μ = 0.5, v₀ = 2 m/s)", "rel. error of stopping distance", "",
              "Box half 0.1 m, 1 kg, on a plane, μ = 0.5, v₀ = 2 m/s. Error: relative error of the "
              "displacement at the end of the horizon against `analytic.slide_distance` "
              "(v₀²/2μg)."),
    "roll": ("Sphere rolling down a 30° slope", "rel. error of acceleration", "",
             "Sphere r = 0.1 m, 1 kg, released at rest on a plane with a 30° tilted normal, μ = 1. "
             "Error: relative error of the downhill acceleration (quadratic fit over t ≥ 0.2 s) "
             "against `analytic.rolling_acceleration` (5/7·g·sin θ)."),
}


def scene_table(points: Sequence[Point]) -> str:
    """Markdown table of one scene's points, Pareto points marked ★.

    Args:
        points: (k,) list of :class:`Point` of one scene, fronts marked.

    Returns:
        The table.
    """
    rows = []
    for p in points:
        rows.append([
            "★" if p.on_front else "", p.group, p.label, config_text(p.scene, p.config),
            fmt_step(p.config["dt"]), fmt_sci(p.error), fmt_sci(p.cost), fmt_fixed(p.step_us, 2),
            fmt_fixed(p.compile_s, 2), fmt_si(p.body_steps_per_s) if p.batch else "—",
            fmt_fixed(p.batch_compile_s, 2) if p.batch else "—"])
    return markdown_table(
        ["★", "group", "label", "configuration", "dt (s)", "error", "s / sim s (b1)", "µs/step (b1)",
         "compile b1 (s)", "body-steps/s (batch)", "compile batch (s)"],
        rows, align=["c", "l", "l", "l", "r", "r", "r", "r", "r", "r", "r"])


def plot_scene(points: Sequence[Point], path: str) -> str:
    """PNG of error against cost, log-log, one panel per dtype (tumbling) or one panel.

    Args:
        points: (k,) list of :class:`Point` of one scene, fronts marked.
        path: file to write.

    Returns:
        ``path``.
    """
    from matplotlib.figure import Figure

    scene = points[0].scene
    title, error_name, unit, _ = SCENE_TEXT[scene]
    panels = list(dict.fromkeys(p.panel for p in points))
    figure = Figure(figsize=(6.4 * len(panels), 4.8))
    for index, panel in enumerate(panels):
        members = [p for p in points if p.panel == panel]
        axis = figure.add_subplot(1, len(panels), index + 1)
        plot_speed_vs_error(axis, [p.cost for p in members], [p.error for p in members],
                            [p.label for p in members], [p.group for p in members],
                            xlabel="wall s per simulated s (batch 1)",
                            ylabel=f"{error_name}{' (' + unit.strip() + ')' if unit else ''}",
                            title=title + ("" if panel == "all" else f" — {panel}"))
        axis.grid(True, which="both", alpha=0.3)
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    return path


def scene_markdown(scene: str, points: Sequence[Point], image: Optional[str] = None) -> str:
    """Heading, description, table, optional image link and summary lines of one scene.

    Args:
        scene: one of :data:`SCENE_NAMES`.
        points: (k,) list of :class:`Point` of that scene, fronts marked.
        image: optional file name of its PNG, linked relative to the report.

    Returns:
        The Markdown block.
    """
    title, error_name, unit, description = SCENE_TEXT[scene]
    horizon = points[0].horizon
    lines = [f"### {title}", "", description + f" Horizon {horizon:g} s.", "",
             f"*error* = {error_name}{unit and ' (' + unit.strip() + ')'}.", "",
             scene_table(points), ""]
    if image:
        lines += [f"![{title}: error against cost]({image})", ""]
    panels = list(dict.fromkeys(p.panel for p in points))
    for panel in panels:
        members = [p for p in points if p.panel == panel]
        prefix = "" if panel == "all" else f"{panel}: "
        lines.append(prefix + summary_line(members, unit))
        lines.append("")
        lines.append(prefix + band_line(members, unit))
        lines.append("")
    return "\n".join(lines).rstrip()


def speed_error_section(settings: dict, log: Optional[Callable] = None):
    """Run the speed-against-error benchmark; return ``(markdown, results)``.

    Args:
        settings: ``speed_error_*`` keys as in :data:`QUICK` / :data:`FULL`
            (missing ones from :data:`QUICK`); ``out_dir`` (or
            ``speed_error_out_dir``): where the PNGs go (none written without
            it); ``repeats`` when ``speed_error_repeats`` is absent.
        log: optional progress callback taking one string.

    Returns:
        ``(markdown, results)``: the section text (one subsection per scene)
        and ``{"scenes": {scene: list of Point}, "images": {scene: PNG path},
        "seconds": wall time of the runs}``.
    """
    merged = _check_settings(settings)
    with Stopwatch() as watch:
        results = run(merged, log)
    out_dir = merged.get("speed_error_out_dir")
    images = {}
    batch_mode = merged["speed_error_batch_configs"]
    batch_text = {"all": "every configuration",
                  "pareto": "the Pareto-front configurations only (to save time)",
                  "cheapest": "the cheapest Pareto-front configuration of each front only "
                              "(to save time)",
                  "none": "no configuration"}[batch_mode]
    parts = [
        "Error against the closed form against cost, for the configurations the engine "
        "offers. *s / sim s (b1)*: median wall time (compile excluded, block_until_ready, up to "
        f"{merged['speed_error_repeats']} calls after a warm-up) of the jitted batch-1 rollout "
        "over the horizon, all states stacked, per simulated second; *compile b1*: trace + lower + "
        f"compile of it. *body-steps/s (batch)*: `jax.vmap` over {merged['speed_error_batch']} "
        f"worlds (each lifted 0–1 mm, spin nudged ≤ 1e-3 rad/s) of a {merged['speed_error_batch_steps']}"
        f"-step rollout in one jit (final state only), measured for {batch_text}; a step includes "
        "its substeps. Contact scenes run in float32. ★: on the Pareto front (no other "
        "configuration is both cheaper and more accurate); cheapest-at-each-level lines read the "
        "front. Timings were taken on a shared machine and are noisy; errors are not.",
    ]
    for scene, points in results.items():
        image = None
        if out_dir:
            os.makedirs(out_dir, exist_ok=True)
            path = plot_scene(points, os.path.join(out_dir, f"speed_error_{scene}.png"))
            images[scene] = path
            image = os.path.basename(path)
        parts.append(scene_markdown(scene, points, image))
    parts.append(f"Speed-against-error wall time: {watch.seconds:.1f} s.")
    return "\n\n".join(parts), {"scenes": results, "images": images, "seconds": watch.seconds}
