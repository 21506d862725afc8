"""The four scenes of the speed-against-error section, their closed forms and their error measures.

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

The metrics are host NumPy, independent of the engine; :func:`trajectory_error`
applies the scene's metric to a rollout. The tumbling scene itself is
:func:`jaxrb.bench.free_body.tumble_scene`.
"""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np

import jaxrb as rb
from jaxrb import analytic
from jaxrb.math import quaternion as quat_ops
from jaxrb.bench.free_body import TUMBLE_ANGVEL, TUMBLE_INERTIA, compare_flips

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
