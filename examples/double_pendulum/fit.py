"""Identify the real DFKI double pendulum with jaxrb: fit, write ``fitted_double_pendulum.json``, score.

Run from the repository root: ``python examples/double_pendulum/fit.py``
(about a minute on 2 CPU cores, half of it compiling). The records (``double_pendulum.npz``
beside this file; provenance in ``DATA.md``) hold measured joint angles q,
velocities qd and motor torques tau of a two-motor double pendulum.

**The model.** Two bodies on two hinges about y (q = 0 hanging down, q2
relative to link 1, a positive torque turns its joint positive), two
``motor`` actuators of gear 1 whose controls are the measured joint torques
(N m), gravity 9.81. Only nine combinations of the physical parameters
enter the motion (given the upper link's length L1 = 0.3 m):

=========  ==================================  =====================================
key        meaning                             where it goes in the scene
=========  ==================================  =====================================
``Th1``    J1 + m2 L1² (kg m²)                 link 1's inertia about its centre
``J2``     link 2's inertia about the elbow    link 2's inertia about its centre
``m2a2``   m2 a2 (kg m), a2 elbow to centre    link 2's centre of mass
``ga``     m1 a1 + m2 L1 (kg m)                link 1's centre of mass
``Jr``     rotor inertia (geared n = 6)        armature (n² + 1) Jr and n² Jr
``b1/b2``  viscous damping (N m s/rad)         joint ``damping``
``mu1/2``  Coulomb friction (N m)              joint ``frictionloss``
=========  ==================================  =====================================

The masses m1, m2 do not enter apart from these (the publishers' values are
kept where they allow the combinations, :func:`geometry`); the armature is diagonal, so the
publishers' −n·Jr coupling term is dropped (it moves their scores by
< 0.7°). Friction is jaxrb's ``smooth`` law μ q̇/√(q̇² + v²) with the
default v = 0.01 rad/s (``exact`` friction scores the same); the step is
MuJoCo's semi-implicit Euler at each sample's interval (about 2 ms).

**The fit.** (1) A starting point from inverse dynamics: linear least
squares of the measured torque on the model's regressor, every column and
the torque smoothed by the same zero-phase low-pass (about 5 Hz; the links
move at frequencies the motor torque does not show above that).
(2) Levenberg–Marquardt on the simulation error: from every 0.05 s of every
record, jaxrb's step is run 0.2 s ahead from the measured angles and the
measured velocities (lightly smoothed, σ = 5 samples, for training only),
driven by the measured torques, and the joint-angle errors (degrees; every
5th sample and the last) are the residuals, each window weighted equally,
errors beyond 2° counted by Huber's loss. Exact forward-mode Jacobians
(``jax.jacfwd``) of log-parameters; short horizons, since long rollouts of
a chaotic pendulum have useless exact gradients (0.3 and 0.5 s windows
scored no better held out). Standard errors are cluster-robust (sandwich,
clusters = 1 s of one record), as in :mod:`jaxrb.fit.least_squares`; they
take the seconds as independent, so the spread of leave-one-record-out
fits (the benchmark's) is the more honest uncertainty.

``fit(records, leave_out=r)`` fits without record r (its windows weigh
zero), which the benchmark's leave-one-record-out cross-validation runs;
every fold reuses one compiled program.
"""

from __future__ import annotations

import dataclasses
import os
import sys
import time
from typing import Optional, Sequence

import jax
import jax.numpy as jnp
import numpy as np

jax.config.update("jax_enable_x64", True)

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(os.path.dirname(HERE))
if REPO not in sys.path:
    sys.path.insert(0, REPO)

import jaxrb as rb  # noqa: E402
from benchmarks import double_pendulum as protocol  # noqa: E402
from jaxrb.fit.least_squares import robust_covariance  # noqa: E402

OUTPUT = os.path.join(HERE, "fitted_double_pendulum.json")

#: The fitted combinations (module docstring), in the order of the parameter vector.
KEYS = ("Th1", "J2", "m2a2", "ga", "Jr", "b1", "b2", "mu1", "mu2")
#: Fixed: upper link length (m), gear ratio, gravity (m/s²), link masses (kg, the publishers';
#: not identifiable), the lower link's length (m, for the picture only).
L1, GEAR, GRAVITY = 0.3, 6.0, 9.81
M1, M2 = protocol.MODEL_2_0["m1"], protocol.MODEL_2_0["m2"]
L2 = 0.2
#: The scene file's nominal step (s): the records' median sample interval.
DT = 0.002
#: How joint friction is solved (``scene.build``'s ``joint_friction``), the integrator and its substeps.
JOINT_FRICTION, INTEGRATOR, SUBSTEPS = "smooth", "semi_implicit", 1
#: The fit's settings: horizon and start spacing (s), residual subsampling, iteration cap, the Huber
#: threshold (degrees) and the smoothing of the windows' start velocities (Gaussian σ, samples).
HORIZON, STRIDE, EVERY, MAX_ITERATIONS, HUBER, START_SMOOTHING = 0.2, 0.05, 5, 20, 2.0, 5.0


# --------------------------------------------------------------------------- #
# The scene
# --------------------------------------------------------------------------- #

def geometry(values: dict) -> dict:
    """Masses (kg), centres of mass (m, along each link) and inertias about them (kg m²) from the combinations.

    The split is not identifiable: each link keeps the publishers' mass
    unless that would leave less than 1 % of its inertia about the joint to
    its inertia about its centre (the centre of mass too far out for the
    inertia), in which case the mass grows just enough. Works on floats and
    on jax scalars.
    """
    maximum = jnp.maximum if isinstance(values["J2"], jax.Array) else max
    m2 = maximum(M2, values["m2a2"] ** 2 / (0.99 * values["J2"]))
    a2 = values["m2a2"] / m2
    arm1, inertia1 = values["ga"] - m2 * L1, values["Th1"] - m2 * L1 ** 2  # m1 a1 and m1 a1² + I1
    m1 = maximum(M1, arm1 ** 2 / (0.99 * inertia1))
    a1 = arm1 / m1
    return dict(m1=m1, m2=m2, a1=a1, a2=a2, I1=inertia1 - m1 * a1 ** 2, I2=values["J2"] - m2 * a2 ** 2)


def scene_from_values(values: dict) -> rb.Scene:
    """The double pendulum as a jaxrb Scene, hanging down (q = 0) in the x–z plane, hinges about y.

    Args:
        values: the combinations of :data:`KEYS` (floats).

    Returns:
        The Scene: bodies ``link1`` (origin at the shoulder) and ``link2``
        (origin at the elbow, L1 below), hinges ``shoulder`` (to the world)
        and ``elbow`` (to link 1), and a ``motor`` of gear 1 on each.
    """
    g = geometry(values)
    if min(g["I1"], g["I2"], g["a1"], values["Th1"] - g["m2"] * L1 ** 2) <= 0.0:
        raise ValueError(f"the combinations give no physical links: {g}")
    scene = rb.Scene(dim=3, gravity=(0.0, 0.0, -GRAVITY))
    # Thin rods along z: the inertia about y is the one that acts; about x the same, about z small.
    link1 = scene.add_body(rb.Capsule(radius=0.02, half_length=L1 / 2), mass=g["m1"],
                           inertia=(g["I1"], g["I1"], 1e-5), com=(0.0, 0.0, -g["a1"]),
                           shape_pos=(0.0, 0.0, -L1 / 2), pos=(0.0, 0.0, 0.0), name="link1")
    link2 = scene.add_body(rb.Capsule(radius=0.02, half_length=L2 / 2), mass=g["m2"],
                           inertia=(g["I2"], g["I2"], 1e-5), com=(0.0, 0.0, -g["a2"]),
                           shape_pos=(0.0, 0.0, -L2 / 2), pos=(0.0, 0.0, -L1), name="link2")
    shoulder = scene.add_joint(rb.Hinge(axis=(0.0, 1.0, 0.0), anchor=(0.0, 0.0, 0.0)), link1, None,
                               damping=values["b1"], armature=(GEAR ** 2 + 1) * values["Jr"],
                               frictionloss=values["mu1"], name="shoulder")
    elbow = scene.add_joint(rb.Hinge(axis=(0.0, 1.0, 0.0), anchor=(0.0, 0.0, -L1)), link2, link1,
                            damping=values["b2"], armature=GEAR ** 2 * values["Jr"],
                            frictionloss=values["mu2"], name="elbow")
    scene.add_actuator(shoulder, "motor", name="shoulder_motor")
    scene.add_actuator(elbow, "motor", name="elbow_motor")
    return scene


def build(values: dict, dtype="float64"):
    """``(model, params, state)`` of :func:`scene_from_values` with the scene file's build options."""
    return scene_from_values(values).build(dt=DT, joint_friction=JOINT_FRICTION, integrator=INTEGRATOR,
                                           substeps=SUBSTEPS, dtype=dtype)


def with_values(params, values: dict):
    """``params`` with the combinations ``values`` (jax scalars) written in: differentiable.

    The masses, inertias, centres of mass, armature, damping and friction change.
    """
    g = geometry(values)
    inertia = params.inertia.at[0, 0, 0].set(g["I1"]).at[0, 1, 1].set(g["I1"])
    inertia = inertia.at[1, 0, 0].set(g["I2"]).at[1, 1, 1].set(g["I2"])
    com = params.com_offset.at[0, 2].set(-g["a1"]).at[1, 2].set(-g["a2"])
    return params.replace(mass=jnp.stack([g["m1"], g["m2"]]).astype(params.mass.dtype), inertia=inertia,
                          com_offset=com,
                          joint_armature=jnp.stack([(GEAR ** 2 + 1) * values["Jr"], GEAR ** 2 * values["Jr"]]),
                          joint_damping=jnp.stack([values["b1"], values["b2"]]),
                          joint_frictionloss=jnp.stack([values["mu1"], values["mu2"]]))


def predictor(values: dict):
    """The scene of ``values`` as a batched ``predict`` of :mod:`benchmarks.double_pendulum`."""
    return protocol.scene_predictor(*build(values))


# --------------------------------------------------------------------------- #
# Starting point: inverse dynamics with consistent smoothing
# --------------------------------------------------------------------------- #

def smooth(x: np.ndarray, sigma: float) -> np.ndarray:
    """Zero-phase Gaussian smoothing along axis 0 (``sigma`` in samples; edges reflected)."""
    radius = int(4 * sigma) + 1
    kernel = np.exp(-0.5 * (np.arange(-radius, radius + 1) / sigma) ** 2)
    kernel /= kernel.sum()
    padded = np.concatenate([x[radius:0:-1], x, x[-2:-radius - 2:-1]], axis=0)
    flat = padded.reshape(len(padded), -1)
    out = np.stack([np.convolve(flat[:, k], kernel, mode="valid") for k in range(flat.shape[1])], axis=1)
    return out.reshape(x.shape)


def regressor(q, w, a) -> np.ndarray:
    """(N, 2, 9) Y with torque_j = Y[:, j] · (values in :data:`KEYS` order), friction as sign(q̇)."""
    q1, q2, w1, w2, a1, a2 = q[:, 0], q[:, 1], w[:, 0], w[:, 1], a[:, 0], a[:, 1]
    cos2, sin2, sin12, zero = np.cos(q2), np.sin(q2), np.sin(q1 + q2), np.zeros_like(q1)
    sign = lambda v: np.clip(v / 0.01, -1.0, 1.0)  # noqa: E731
    shoulder = [a1, a1 + a2, L1 * (2 * cos2 * a1 + cos2 * a2 - sin2 * (2 * w1 * w2 + w2 ** 2)) + GRAVITY * sin12,
                GRAVITY * np.sin(q1), (GEAR ** 2 + 1) * a1, w1, zero, sign(w1), zero]
    elbow = [zero, a1 + a2, L1 * (cos2 * a1 + sin2 * w1 ** 2) + GRAVITY * sin12, zero, GEAR ** 2 * a2,
             zero, w2, zero, sign(w2)]
    return np.stack([np.stack(shoulder, 1), np.stack(elbow, 1)], 1)


def inverse_dynamics(records: Sequence, cutoff: float = 5.0) -> dict:
    """Least-squares combinations from the torque equation (the fit's starting point).

    Velocities are the driver's, lightly smoothed; accelerations are
    differences of them. Every regressor column and the torque then pass
    through the same Gaussian low-pass of -3 dB at ``cutoff`` Hz, so the
    nonlinear columns see the filter the torque sees ("parallel filtering").
    """
    rows, torques = [], []
    for record in records:
        step = float(np.median(np.diff(record.t)))
        w = smooth(record.qd, 2.0)
        a = np.gradient(w, record.t, axis=0)
        sigma = 0.133 / (cutoff * step)
        y = smooth(regressor(record.q, w, a).reshape(len(record.t), -1), sigma).reshape(-1, 2, len(KEYS))
        rows.append(y.reshape(-1, len(KEYS)))
        torques.append(smooth(record.tau, sigma).reshape(-1))
    solution, *_ = np.linalg.lstsq(np.concatenate(rows), np.concatenate(torques), rcond=None)
    return {key: float(value) for key, value in zip(KEYS, solution)}


# --------------------------------------------------------------------------- #
# Simulation-error fit
# --------------------------------------------------------------------------- #

def training_windows(records: Sequence, horizon: float = HORIZON, stride: float = STRIDE, every: int = EVERY,
                     start_smoothing: float = 0.0):
    """Windows of ``horizon`` s from every ``stride`` s, padded into one batch per sampling rate.

    Args:
        start_smoothing: Gaussian σ (samples) of the start velocities; 0 keeps the measured ones.

    Returns:
        A tuple of dicts of arrays: ``q0``, ``qd0`` (S, 2); ``dt`` (S, K−1);
        ``tau`` (S, K−1, 2); ``q`` (S, K, 2) measured; ``mask`` (S, K) the
        scored samples (every ``every``-th and the last); ``record`` (S,);
        ``block`` (S,) the window's cluster (record and whole second).
    """
    batches = {}
    blocks = 0
    for r, record in enumerate(records):
        t = record.t
        starts = protocol.start_indices(t, spacing=stride, longest=horizon)
        ends = np.searchsorted(t, t[starts] + horizon, side="left")
        width = int((ends - starts).max()) + 1
        rate = round(float(np.median(np.diff(t))), 4)
        size = len(starts)
        qd = smooth(record.qd, start_smoothing) if start_smoothing > 0 else record.qd
        out = dict(q0=record.q[starts], qd0=qd[starts], dt=np.zeros((size, width - 1)),
                   tau=np.zeros((size, width - 1, 2)), q=np.zeros((size, width, 2)), mask=np.zeros((size, width)),
                   record=np.full(size, r), block=blocks + np.floor(t[starts]).astype(int))
        blocks = int(out["block"].max()) + 1
        for s, (i, j) in enumerate(zip(starts, ends)):
            n = j - i + 1
            out["dt"][s, :n - 1] = np.diff(t[i:j + 1])
            out["tau"][s, :n - 1] = record.tau[i:j]
            out["q"][s, :n], out["q"][s, n:] = record.q[i:j + 1], record.q[j]
            out["mask"][s, every:n:every] = 1.0
            out["mask"][s, n - 1] = 1.0
        batches.setdefault(rate, []).append(out)
    merged = []
    for rate in sorted(batches):
        group = batches[rate]
        width = max(b["q"].shape[1] for b in group)

        def pad(x, length, fill=None):
            """``x`` (S, k, ...) to (S, length, ...) along axis 1: ``fill``, or its last entry repeated."""
            extra = length - x.shape[1]
            tail = np.repeat(x[:, -1:], extra, axis=1) if fill is None else np.full((len(x), extra) + x.shape[2:], fill)
            return np.concatenate([x, tail], axis=1)

        merged.append(dict(
            q0=np.concatenate([b["q0"] for b in group]), qd0=np.concatenate([b["qd0"] for b in group]),
            dt=np.concatenate([pad(b["dt"], width - 1, 0.0) for b in group]),  # padded intervals last 0 s
            tau=np.concatenate([pad(b["tau"], width - 1) for b in group]),
            q=np.concatenate([pad(b["q"], width) for b in group]),
            mask=np.concatenate([pad(b["mask"], width, 0.0) for b in group]),
            record=np.concatenate([b["record"] for b in group]),
            block=np.concatenate([b["block"] for b in group])))
    return tuple(merged)


_PROGRAMS: list = []


def _programs():
    """Jitted ``cost(theta, weights, data, huber)`` and ``linearize(...)`` (built once).

    ``data`` is :func:`training_windows`' batches (arrays), ``weights`` one
    (S,) array per batch scaling each window's residuals: 1/√(its scored
    samples), or 0 for a left-out record; errors beyond ``huber`` degrees
    count by Huber's loss (linearly). The programs compile once per
    window shape, so the cross-validation's folds share them. ``linearize``
    returns the cost, JᵀJ, Jᵀr and each window's gradient (S_total, 9).
    """
    if _PROGRAMS:
        return _PROGRAMS[0]
    start = dict(Th1=0.1, J2=0.025, m2a2=0.11, ga=0.33, Jr=1e-4, b1=0.01, b2=0.01, mu1=0.1, mu2=0.1)
    model, template, state = build(start)  # the values enter as arguments; any physical start will do
    rollout = jax.vmap(protocol.scene_rollout(model, state), in_axes=(None, 0, 0, 0, 0))

    def residuals(theta, weights, data, huber):
        params = with_values(template, {k: jnp.exp(theta[i]) for i, k in enumerate(KEYS)})
        out = []
        for batch, weight in zip(data, weights):
            q = rollout(params, batch["q0"], batch["qd0"], batch["dt"], batch["tau"])
            scale = (batch["mask"] * weight[:, None])[..., None]
            error = jnp.degrees(q - batch["q"])
            size = jnp.abs(error) + 1e-12  # Huber's loss: ½ r² inside, huber·(|r| − huber/2) outside
            error = jnp.where(size > huber, error / size * jnp.sqrt(2 * huber * size - huber ** 2), error)
            out.append((error * scale).reshape(-1))
        return jnp.concatenate(out)

    def cost(theta, weights, data, huber):
        r = residuals(theta, weights, data, huber)
        return 0.5 * jnp.sum(r * r)

    def linearize(theta, weights, data, huber):
        r = residuals(theta, weights, data, huber)
        jacobian = jax.jacfwd(residuals)(theta, weights, data, huber)
        rows = [b["q"].shape[1] * 2 for b in data]  # residuals per window, batch by batch
        per_window, at = [], 0
        for batch, width in zip(data, rows):
            count = batch["q"].shape[0] * width
            piece = (jacobian[at:at + count] * r[at:at + count, None]).reshape(-1, width, len(KEYS))
            per_window.append(piece.sum(axis=1))
            at += count
        return 0.5 * jnp.sum(r * r), jacobian.T @ jacobian, jacobian.T @ r, jnp.concatenate(per_window)

    _PROGRAMS.append((jax.jit(cost), jax.jit(linearize)))
    return _PROGRAMS[0]


@dataclasses.dataclass
class Fit:
    """A fitted double pendulum.

    Attributes:
        values: the combinations of :data:`KEYS`.
        standard_errors: their cluster-robust standard errors (same units).
        covariance: (9, 9) covariance of the log-values.
        start: the inverse-dynamics starting point.
        cost: final ½ Σ r² (degrees², windows weighted equally); history: per iteration.
        iterations, stopped, seconds: how the fit went (seconds include compiling).
    """

    values: dict
    standard_errors: dict
    covariance: np.ndarray
    start: dict
    cost: float
    history: list
    iterations: int
    stopped: str
    seconds: float

    def table(self) -> str:
        """The values ± standard errors (relative error in brackets), one line each."""
        return "\n".join(f"{k:5s} {self.values[k]:.5g} ± {self.standard_errors[k]:.2g} "
                         f"({100 * self.standard_errors[k] / self.values[k]:.1f} %)" for k in KEYS)


def fit(records: Sequence, *, leave_out: Optional[int] = None, horizon: float = HORIZON, stride: float = STRIDE,
        every: int = EVERY, max_iterations: int = MAX_ITERATIONS, tol: float = 1e-6, huber: float = HUBER,
        start_smoothing: float = START_SMOOTHING, log=print) -> Fit:
    """Fit the combinations to ``records`` (module docstring): inverse dynamics, then Levenberg–Marquardt.

    Args:
        records: :class:`benchmarks.double_pendulum.Record` s.
        leave_out: index of a record to leave out (cross-validation), or None.
        horizon, stride: window length and start spacing (s).
        every: residuals at every ``every``-th sample of a window (and its last).
        max_iterations: Levenberg–Marquardt iterations at most.
        tol: stop when an accepted step lowers the cost by less than this fraction.
        huber: errors beyond this (degrees) count linearly (Huber's loss), so the few windows that
            chaos or a stuck joint throws far off do not steer the fit.
        start_smoothing: Gaussian σ (samples) of the velocities the training windows start from
            (the measured ones carry 0.095 rad/s of noise; 0 keeps them as measured).
        log: progress lines.

    Returns:
        :class:`Fit`.
    """
    clock = time.perf_counter()
    kept = [record for r, record in enumerate(records) if r != leave_out]
    start = inverse_dynamics(kept)
    start = {k: max(v, 1e-6) for k, v in start.items()}
    log("inverse dynamics: " + ", ".join(f"{k} {start[k]:.4g}" for k in KEYS))
    batches = training_windows(records, horizon, stride, every, start_smoothing)
    weights = tuple(jnp.asarray(np.where(b["record"] == leave_out, 0.0, 1.0 / np.sqrt(b["mask"].sum(1))))
                    for b in batches)
    data = tuple({k: jnp.asarray(b[k]) for k in ("q0", "qd0", "dt", "tau", "q", "mask")} for b in batches)
    blocks = np.concatenate([b["block"] for b in batches])
    cost_of, linearize = _programs()

    def linearized(theta):
        cost, hessian, gradient, per_window = (np.asarray(x) for x in linearize(jnp.asarray(theta), weights, data,
                                                                                  huber))
        per_block = np.zeros((blocks.max() + 1, len(KEYS)))
        np.add.at(per_block, blocks, per_window)
        return cost, hessian, gradient, per_block

    theta = np.log(np.array([start[k] for k in KEYS]))
    cost, hessian, gradient, per_block = linearized(theta)
    lam, history, stopped, iteration = 1e-2, [float(cost)], "iterations", 0
    log(f"iteration 0: cost {cost:.6g} ({time.perf_counter() - clock:.1f} s, compile included)")
    while iteration < max_iterations:
        iteration += 1
        damped = hessian + lam * np.diag(np.maximum(np.diag(hessian), 1e-12))
        trial = theta - np.linalg.solve(damped, gradient)
        trial_cost = float(cost_of(jnp.asarray(trial), weights, data, huber))
        if np.isfinite(trial_cost) and trial_cost < cost:
            relative = (cost - trial_cost) / cost
            theta, lam = trial, max(lam / 3.0, 1e-9)
            cost, hessian, gradient, per_block = linearized(theta)
            history.append(float(cost))
            log(f"iteration {iteration}: cost {cost:.6g}, λ {lam:.2g} ({time.perf_counter() - clock:.1f} s)")
            if relative < tol:
                stopped = "converged"
                break
        else:
            lam *= 4.0
            if lam > 1e8:
                stopped = "converged"
                break
    covariance = robust_covariance(hessian, per_block)
    values = {k: float(np.exp(theta[i])) for i, k in enumerate(KEYS)}
    errors = {k: values[k] * float(np.sqrt(max(covariance[i, i], 0.0))) for i, k in enumerate(KEYS)}
    return Fit(values=values, standard_errors=errors, covariance=covariance, start=start, cost=float(cost),
               history=history, iterations=iteration, stopped=stopped, seconds=time.perf_counter() - clock)


def save(values: dict, path: str = OUTPUT) -> None:
    """Write the scene of ``values`` as a jaxrb JSON scene file (dt = 0.002 s, smooth joint friction)."""
    options = dict(dt=DT, joint_friction=JOINT_FRICTION)
    if INTEGRATOR != "semi_implicit" or SUBSTEPS != 1:
        options.update(integrator=INTEGRATOR, substeps=SUBSTEPS)
    rb.save_scene(path, scene_from_values(values), **options)


def main() -> None:
    records = protocol.load_records()
    print(f"{len(records)} records, {len(protocol.windows(records))} scored starts")
    result = fit(records)
    print(f"fitted in {result.seconds:.1f} s ({result.iterations} iterations, {result.stopped}):")
    print(result.table())
    save(result.values)
    print(f"wrote {os.path.relpath(OUTPUT, REPO)}")
    model, params, state = protocol.load_fitted(OUTPUT)
    rows = {"jaxrb, fitted (in-sample)": protocol.scene_predictor(model, params, state),
            "model_2.0 (publishers)": protocol.plant_predictor(),
            "constant velocity": protocol.constant_velocity}
    print("end both (degrees) at 0.05 / 0.2 / 0.5 s:")
    for name, predict in rows.items():
        print(f"  {name:28s} " + " / ".join(f"{x:.2f}" for x in protocol.end_both(protocol.score(predict, records))))


if __name__ == "__main__":
    main()
