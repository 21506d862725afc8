"""Free-body benchmarks: integrator accuracy on a tumbling body, and step throughput.

1. **Torque-free tumbling** (the intermediate-axis or "Dzhanibekov" flip). A body
   with principal inertia (0.3, 0.35, 0.4) kg m² spins about its intermediate
   axis, ω0 = (0.1, 15, 0.1) rad/s in the body frame, no gravity. The spin flips
   periodically; the flip times (sign changes of body-frame ω_y) are a sharp
   test of how well an integrator follows the rotational dynamics. The
   reference comes from Euler's equations integrated here in float64 with
   classic RK4 at a step ≤ 1e-4 s (plain Python, independent of jaxrb).
   Reported per integrator, orientation update and step h: the largest
   flip-time error, the kinetic-energy drift E(T)/E(0) − 1, the largest
   relative drift of the world angular momentum, and compile and run times.

2. **Throughput**: body-steps per second of a jitted free-body step (a few
   boxes under gravity) at batch 1 and under ``jax.vmap`` at a large batch,
   with a rollout scanned inside one jit.

The functions here return Markdown strings (and the raw numbers) so that the
command line in :mod:`jaxrb.bench.__main__` can assemble one report.
"""

from __future__ import annotations

import dataclasses
import math
import sys
from typing import Optional, Sequence

import jax
import jax.numpy as jnp
import numpy as np

import jaxrb as rb
from jaxrb.math import quaternion as quat_ops
from jaxrb.bench.report import fmt_fixed, fmt_sci, fmt_si, fmt_step, markdown_table
from jaxrb.bench.timing import Stopwatch, final_state_fn, time_jitted
from jaxrb.model.types import QUATERNION_ODE_INTEGRATORS

# --- the tumbling problem ------------------------------------------------------------------

TUMBLE_INERTIA = (0.3, 0.35, 0.4)  # principal moments, kg m²; y is the intermediate axis
TUMBLE_ANGVEL = (0.1, 15.0, 0.1)  # body-frame ω0, rad/s (identity orientation: also world)
#: Flip times over 20 s quoted in the brief (Jacobi elliptic solution); the
#: benchmark recomputes its own reference and shows these beside it.
TUMBLE_QUOTED_FLIPS = (3.692, 9.859, 16.027)
REFERENCE_MAX_STEP = 1e-4

TUMBLE_CONFIGS = (
    ("euler", "first_order"), ("euler", "exp_map"),
    ("semi_implicit", "first_order"), ("semi_implicit", "exp_map"),
    ("implicit_gyro", "first_order"), ("implicit_gyro", "exp_map"),
    ("rk4", None), ("rk4_body", None),
)


def euler_equations_rk4(inertia: Sequence[float], angvel0: Sequence[float], t_end: float,
                        h: float) -> np.ndarray:
    """Body-frame ω of a torque-free body by classic RK4 on Euler's equations, float64.

    I1 ω̇1 = (I2 − I3) ω2 ω3 and cyclic. Written on Python floats: for three
    components this is far faster than NumPy arrays and needs nothing but the
    standard library.

    Args:
        inertia: (3,) principal moments.
        angvel0: (3,) initial body-frame angular velocity.
        t_end: horizon, s.
        h: step, s; ``t_end / h`` is rounded to an integer number of steps.

    Returns:
        (num_steps + 1, 3) body-frame ω at t = 0, h, 2h, ...
    """
    i1, i2, i3 = (float(v) for v in inertia)
    a1, a2, a3 = (i2 - i3) / i1, (i3 - i1) / i2, (i1 - i2) / i3
    x, y, z = (float(v) for v in angvel0)
    num_steps = int(round(t_end / h))
    out = np.empty((num_steps + 1, 3))
    out[0] = x, y, z
    half, sixth = 0.5 * h, h / 6.0
    for k in range(num_steps):
        k1x, k1y, k1z = a1 * y * z, a2 * z * x, a3 * x * y
        x2, y2, z2 = x + half * k1x, y + half * k1y, z + half * k1z
        k2x, k2y, k2z = a1 * y2 * z2, a2 * z2 * x2, a3 * x2 * y2
        x3, y3, z3 = x + half * k2x, y + half * k2y, z + half * k2z
        k3x, k3y, k3z = a1 * y3 * z3, a2 * z3 * x3, a3 * x3 * y3
        x4, y4, z4 = x + h * k3x, y + h * k3y, z + h * k3z
        k4x, k4y, k4z = a1 * y4 * z4, a2 * z4 * x4, a3 * x4 * y4
        x += sixth * (k1x + 2.0 * k2x + 2.0 * k3x + k4x)
        y += sixth * (k1y + 2.0 * k2y + 2.0 * k3y + k4y)
        z += sixth * (k1z + 2.0 * k2z + 2.0 * k3z + k4z)
        out[k + 1] = x, y, z
    return out


def sign_changes(times: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Times where ``values`` changes sign, located by linear interpolation.

    Args:
        times: (m,) increasing sample times.
        values: (m,) samples.

    Returns:
        (k,) crossing times, increasing. Non-finite samples end the search
        (a blown-up run has no meaningful flips after that).
    """
    times = np.asarray(times, dtype=np.float64)
    values = np.asarray(values, dtype=np.float64)
    finite = np.isfinite(values)
    if not finite.all():
        cut = int(np.argmin(finite))
        times, values = times[:cut], values[:cut]
    positive = values > 0.0
    index = np.nonzero(positive[:-1] != positive[1:])[0]
    v0, v1 = values[index], values[index + 1]
    return times[index] + (times[index + 1] - times[index]) * v0 / (v0 - v1)


@dataclasses.dataclass
class FlipError:
    """Flip times of a run against the reference."""

    times: np.ndarray
    num_reference: int
    max_error: float  # inf when flips are missing

    @property
    def count_text(self) -> str:
        return f"{len(self.times)}/{self.num_reference}"

    def text(self, digits: int = 2) -> str:
        value = fmt_sci(self.max_error, digits)
        if len(self.times) < self.num_reference:
            return f"{value} (missing: {self.count_text} flips)"
        if len(self.times) > self.num_reference:
            return f"{value} ({self.count_text} flips)"
        return value


def compare_flips(times: np.ndarray, reference: np.ndarray) -> FlipError:
    """Largest |t_i − t_ref,i| over the reference flips; inf if the run has fewer flips.

    A run with *more* flips than the reference is compared on the first
    ``len(reference)`` of them (its count is reported beside the error).
    """
    if len(reference) == 0:
        return FlipError(times, 0, 0.0)
    if len(times) < len(reference):
        return FlipError(times, len(reference), math.inf)
    error = float(np.max(np.abs(times[:len(reference)] - reference)))
    return FlipError(times, len(reference), error)


@dataclasses.dataclass
class TumbleReference:
    """Reference flip times and how far they can be trusted."""

    flip_times: np.ndarray
    step: float
    uncertainty: float  # max |flip(h) − flip(2h)|, an upper estimate of the RK4 error
    seconds: float


def tumble_reference(t_end: float, max_step: float = REFERENCE_MAX_STEP) -> TumbleReference:
    """Reference flip times of the tumbling body over ``[0, t_end]``."""
    with Stopwatch() as watch:
        fine = euler_equations_rk4(TUMBLE_INERTIA, TUMBLE_ANGVEL, t_end, max_step)
        coarse = euler_equations_rk4(TUMBLE_INERTIA, TUMBLE_ANGVEL, t_end, 2.0 * max_step)
    flips = sign_changes(np.arange(len(fine)) * max_step, fine[:, 1])
    flips_coarse = sign_changes(np.arange(len(coarse)) * 2.0 * max_step, coarse[:, 1])
    uncertainty = (float(np.max(np.abs(flips - flips_coarse)))
                   if len(flips) == len(flips_coarse) and len(flips) else math.nan)
    return TumbleReference(flips, max_step, uncertainty, watch.seconds)


def interpolation_floor(h: float, t_end: float, reference: np.ndarray) -> float:
    """Flip-time error that linear interpolation alone causes when sampling every ``h``.

    The exact solution (RK4 at a step h/m ≤ 1e-4) is sampled every h and its
    flips located as for the benchmarked runs; an integrator cannot be judged
    more accurately than this with samples every h.
    """
    substeps = max(1, math.ceil(h / REFERENCE_MAX_STEP - 1e-9))
    fine = euler_equations_rk4(TUMBLE_INERTIA, TUMBLE_ANGVEL, t_end, h / substeps)
    sampled = fine[::substeps, 1]
    flips = sign_changes(np.arange(len(sampled)) * h, sampled)
    return compare_flips(flips, reference).max_error


def tumble_scene():
    scene = rb.Scene(dim=3, gravity=(0.0, 0.0, 0.0))
    scene.add_body(None, mass=1.0, inertia=TUMBLE_INERTIA, angvel=TUMBLE_ANGVEL, name="tumbler")
    return scene


@dataclasses.dataclass
class TumbleResult:
    integrator: str
    orientation: Optional[str]
    h: float
    dtype: str
    flips: FlipError
    energy_drift: float  # E(T)/E(0) − 1
    max_energy_gain: float  # max_t E(t)/E(0) − 1 (≤ 0: never gained energy)
    momentum_drift: float  # max_t |L(t) − L(0)| / |L(0)|, world frame
    compile_s: float
    run_s: float
    num_steps: int


def run_tumble(integrator: str, orientation: Optional[str], h: float, t_end: float, dtype,
               reference: np.ndarray, repeats: int = 5) -> TumbleResult:
    """Roll the tumbling body out for ``t_end`` at step ``h`` and measure it."""
    num_steps = int(round(t_end / h))
    model, params, state = tumble_scene().build(dt=h, integrator=integrator,
                                                orientation=orientation, dtype=dtype)
    step = rb.make_step(model)

    def trajectory(state0, params0):
        return rb.rollout(step, state0, params0, num_steps)

    timing = time_jitted(trajectory, state, params, repeats=repeats, budget_s=5.0)
    traj = timing.output
    # Metrics in float64 on the host, whatever the run's dtype; time is k·h exactly
    # (state.time accumulates round-off in float32).
    quat = np.concatenate([np.asarray(state.quat)[None], np.asarray(traj.quat)])[:, 0]
    angvel = np.concatenate([np.asarray(state.angvel)[None], np.asarray(traj.angvel)])[:, 0]
    quat, angvel = quat.astype(np.float64), angvel.astype(np.float64)
    inertia = np.asarray(TUMBLE_INERTIA)
    body_angvel = np.asarray(quat_ops.rotate_inverse(quat, angvel))
    body_momentum = inertia * body_angvel
    energy = 0.5 * np.sum(body_momentum * body_angvel, axis=-1)
    momentum = np.asarray(quat_ops.rotate(quat, body_momentum))
    times = np.arange(num_steps + 1) * h
    flips = compare_flips(sign_changes(times, body_angvel[:, 1]), reference)
    momentum_change = np.linalg.norm(momentum - momentum[0], axis=-1) / np.linalg.norm(momentum[0])
    return TumbleResult(
        integrator=integrator, orientation=orientation, h=h, dtype=jnp.dtype(dtype).name,
        flips=flips, energy_drift=float(energy[-1] / energy[0] - 1.0),
        max_energy_gain=float(np.max(energy / energy[0]) - 1.0),
        momentum_drift=float(np.max(momentum_change)) if np.all(np.isfinite(momentum_change))
        else math.inf,
        compile_s=timing.compile_s, run_s=timing.run_s, num_steps=num_steps)


def _order(errors: Sequence[float], steps: Sequence[float]) -> list:
    """Observed order log(e_i/e_j)/log(h_i/h_j) between consecutive step sizes."""
    orders = []
    for (e0, h0), (e1, h1) in zip(zip(errors, steps), zip(errors[1:], steps[1:])):
        e0, e1 = abs(e0), abs(e1)
        if e0 > 0 and e1 > 0 and math.isfinite(e0) and math.isfinite(e1):
            orders.append(math.log(e0 / e1) / math.log(h0 / h1))
        else:
            orders.append(None)
    return orders


def tumbling_section(steps: Sequence[float], t_end: float, repeats: int = 5, log=None,
                     configs: Sequence[tuple] = TUMBLE_CONFIGS):
    """Run the tumbling benchmark; return ``(markdown, results)``.

    ``configs``: (integrator, orientation update) pairs, default every one
    the engine offers (:data:`TUMBLE_CONFIGS`).

    Needs ``jax_enable_x64`` (the float64 runs); float32 runs are built with an
    explicit dtype.
    """
    if not jax.config.jax_enable_x64:
        raise RuntimeError("the tumbling benchmark needs jax_enable_x64 (float64 runs)")
    log = log or (lambda text: None)
    reference = tumble_reference(t_end)
    log(f"reference: flips {np.round(reference.flip_times, 6).tolist()} "
        f"({reference.seconds:.2f} s)")
    floors = {h: interpolation_floor(h, t_end, reference.flip_times) for h in steps}

    results = []
    for integrator, orientation in configs:
        for h in steps:
            pair = {}
            for dtype in (jnp.float64, jnp.float32):
                pair[jnp.dtype(dtype).name] = run_tumble(integrator, orientation, h, t_end, dtype,
                                                         reference.flip_times, repeats)
            log(f"tumbling {integrator:>13} {orientation or '-':>11} h={fmt_step(h):>6}: "
                f"flip err {pair['float64'].flips.text()} (f32 {pair['float32'].flips.text()}), "
                f"compile {pair['float64'].compile_s:.2f} s, run {1e3 * pair['float64'].run_s:.1f} ms")
            results.append(pair)

    quoted = ", ".join(f"{t:.3f}" for t in TUMBLE_QUOTED_FLIPS if t <= t_end)
    lines = [
        f"Body with principal inertia {TUMBLE_INERTIA} kg m², no gravity, body-frame "
        f"ω0 = {TUMBLE_ANGVEL} rad/s, identity orientation, horizon T = {t_end:g} s.",
        "",
        f"Reference: Euler's equations, classic RK4 in float64 at h = {reference.step:g} s "
        f"(plain Python, {reference.seconds:.2f} s). Flip times (body-frame ω_y sign changes, "
        f"linear interpolation): **{', '.join(f'{t:.6f}' for t in reference.flip_times)} s**; "
        f"max change against h = {2 * reference.step:g} s: {fmt_sci(reference.uncertainty)} s. "
        f"Quoted values: {quoted or '(none in horizon)'} s.",
        "",
        "Flip-time error floor from locating flips by linear interpolation between samples "
        "h apart (exact solution sampled every h): "
        + ", ".join(f"h = {fmt_step(h)}: {fmt_sci(floors[h])} s" for h in steps) + ".",
        "",
        "Columns: *flips* = flips found in float64 / reference flips; *flip err* = max "
        "|t_flip − t_ref| over the reference flips (inf if flips are missing); "
        "*E drift* = E(T)/E(0) − 1; *max E gain* = max_t E(t)/E(0) − 1 (≤ 0: the run never "
        "gained energy); *L drift* = max_t ‖L(t) − L(0)‖/‖L(0)‖ (world frame); "
        "*compile* = trace + lower + compile of the jitted rollout; *run* = median wall time "
        "of the jitted T-second rollout (all states stacked) with block_until_ready.",
        "",
    ]
    rows = []
    for pair in results:
        r64, r32 = pair["float64"], pair["float32"]
        rows.append([
            r64.integrator, r64.orientation or "—", fmt_step(r64.h), r64.flips.count_text,
            r64.flips.text(), r32.flips.text(), fmt_sci(r64.energy_drift),
            fmt_sci(r64.max_energy_gain),
            fmt_sci(r64.momentum_drift), fmt_sci(r32.energy_drift), fmt_fixed(r64.compile_s, 2),
            fmt_fixed(1e3 * r64.run_s, 1), fmt_fixed(1e3 * r32.run_s, 1),
            fmt_fixed(1e6 * r64.run_s / r64.num_steps, 2),
        ])
    lines.append(markdown_table(
        ["integrator", "orientation", "h (s)", "flips", "flip err f64 (s)", "flip err f32 (s)",
         "E drift f64", "max E gain f64", "L drift f64", "E drift f32", "compile f64 (s)", "run f64 (ms)",
         "run f32 (ms)", "µs/step f64"],
        rows, align=["l", "l", "r", "c"] + ["r"] * 10))

    if len(steps) > 1:
        lines += ["", "Observed order between consecutive step sizes, log(e1/e2)/log(h1/h2), "
                      "float64 (— where an error is zero, missing or inf):", ""]
        order_rows = []
        for index in range(0, len(results), len(steps)):
            block = [pair["float64"] for pair in results[index:index + len(steps)]]
            flip_orders = _order([r.flips.max_error for r in block], steps)
            energy_orders = _order([r.energy_drift for r in block], steps)
            momentum_orders = _order([r.momentum_drift for r in block], steps)
            row = [block[0].integrator, block[0].orientation or "—"]
            row += [", ".join(fmt_fixed(o, 2) for o in orders)
                    for orders in (flip_orders, energy_orders, momentum_orders)]
            order_rows.append(row)
        pairs_text = ", ".join(f"{fmt_step(a)}→{fmt_step(b)}" for a, b in zip(steps, steps[1:]))
        lines.append(markdown_table(
            ["integrator", "orientation", f"flip err ({pairs_text})", f"|E drift| ({pairs_text})",
             f"L drift ({pairs_text})"], order_rows, align=["l", "l", "r", "r", "r"]))
    return "\n".join(lines), {"reference": reference, "floors": floors, "results": results}


# --- throughput -----------------------------------------------------------------------------

def throughput_scene(num_bodies: int = 8, seed: int = 0):
    """A few free boxes of different sizes, spinning and falling under gravity (no contact)."""
    rng = np.random.default_rng(seed)
    scene = rb.Scene(dim=3)
    for index in range(num_bodies):
        quat = rng.normal(size=4)
        scene.add_body(rb.Box(half_extents=tuple(rng.uniform(0.05, 0.3, size=3))),
                       mass=float(rng.uniform(0.5, 2.0)), pos=(1.0 * index, 0.0, 2.0),
                       quat=tuple(quat / np.linalg.norm(quat)), vel=tuple(rng.normal(size=3)),
                       angvel=tuple(rng.normal(scale=3.0, size=3)), name=f"box{index}")
    return scene


def _batched_state(state, batch: int, seed: int = 1):
    """``batch`` copies of ``state`` with different velocities (so no world is a copy)."""
    rng = np.random.default_rng(seed)

    def tile(array):
        return jnp.broadcast_to(array, (batch,) + array.shape)

    batched = jax.tree_util.tree_map(tile, state)
    dtype = state.vel.dtype
    return batched.replace(
        vel=batched.vel + jnp.asarray(rng.normal(scale=0.1, size=batched.vel.shape), dtype),
        angvel=batched.angvel + jnp.asarray(rng.normal(scale=0.3, size=batched.angvel.shape), dtype))


@dataclasses.dataclass
class ThroughputResult:
    integrator: str
    orientation: Optional[str]
    batch: int
    num_bodies: int
    num_steps: int
    compile_s: float
    run_s: float

    @property
    def body_steps_per_s(self) -> float:
        return self.batch * self.num_bodies * self.num_steps / self.run_s


def run_throughput(integrator: str, batch: int, num_steps: int, num_bodies: int = 8,
                   dt: float = 1e-3, dtype=jnp.float32, repeats: int = 5) -> ThroughputResult:
    """Time ``num_steps`` steps scanned inside one jit, for one world or ``batch`` vmapped worlds.

    The steps run as ``rb.rollout`` runs them (``jax.vmap``-ed over worlds
    when ``batch > 1``). Only the final state is returned, so the timing is
    the step's, not the cost of storing a trajectory.
    """
    # contact="none": the boxes never touch, and without it the velocity-first
    # integrators would get the default impulse solver over all 28 box pairs.
    model, params, state = throughput_scene(num_bodies).build(dt=dt, integrator=integrator,
                                                              contact="none", dtype=dtype)
    step = rb.make_step(model)
    if batch > 1:
        state = _batched_state(state, batch)
    timing = time_jitted(final_state_fn(step, num_steps, batch > 1), state, params, repeats=repeats,
                         budget_s=10.0)
    if not bool(jnp.all(jnp.isfinite(timing.output.pos))):
        raise FloatingPointError(f"throughput run {integrator} batch {batch} went non-finite")
    orientation = None if integrator in QUATERNION_ODE_INTEGRATORS else model.orientation
    return ThroughputResult(integrator, orientation, batch, num_bodies, num_steps, timing.compile_s,
                            timing.run_s)


def throughput_section(integrators: Sequence[str], batches: Sequence[int], num_steps: int,
                       num_bodies: int = 8, repeats: int = 5, log=None):
    """Run the throughput benchmark; return ``(markdown, results)``."""
    log = log or (lambda text: None)
    results = []
    for integrator in integrators:
        for batch in batches:
            result = run_throughput(integrator, batch, num_steps, num_bodies, repeats=repeats)
            log(f"throughput {integrator:>13} batch {batch:>5}: compile {result.compile_s:.2f} s, "
                f"run {result.run_s:.3f} s, {fmt_si(result.body_steps_per_s, ' body-steps/s')}")
            results.append(result)
    lines = [
        f"{num_bodies} free boxes (different sizes, masses, spins), gravity on, no contact, "
        f"float32, dt = 1e-3 s. {num_steps} steps of `rb.rollout` inside one jit (final state "
        "only); larger batches are `jax.vmap` of it over states. *compile* = trace + lower + compile; "
        "*run* = median wall time of the whole scan with block_until_ready; "
        "body-steps/s = batch · bodies · steps / run.",
        "",
        markdown_table(
            ["integrator", "orientation", "batch", "compile (s)", "run (s)", "µs/step",
             "body-steps/s"],
            [[r.integrator, r.orientation or "—", r.batch, fmt_fixed(r.compile_s, 2),
              fmt_fixed(r.run_s, 4), fmt_fixed(1e6 * r.run_s / r.num_steps, 2),
              fmt_si(r.body_steps_per_s)] for r in results],
            align=["l", "l", "r", "r", "r", "r", "r"]),
    ]
    return "\n".join(lines), results


def stderr_log(text: str):
    print(text, file=sys.stderr, flush=True)
