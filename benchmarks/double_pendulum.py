"""Real double pendulum (DFKI design A.0): the publishers' scoring protocol, their model, and jaxrb's fit.

The data (``examples/double_pendulum/double_pendulum.npz``, or the file named
by the ``JAXRB_DOUBLE_PENDULUM`` environment variable; provenance and format
in ``examples/double_pendulum/DATA.md``) holds 6 system-identification records
of a real two-motor double pendulum: measured joint angles ``q``, velocities
``qd`` and motor torques ``tau``, sampled at about 2 ms with jitter.

**The protocol** (the data's README, "Scoring protocol"). In every record,
start at the first sample at or after 0, 0.1, 0.2, ... s, while the start
time plus 0.5 s stays within the record. From start sample i a model gets
the measured state (q[i], qd[i]) and the measured torques tau[i], tau[i+1],
..., each held over its own interval [t[k], t[k+1]), and predicts q at the
following sample times. Horizon H ends at the first sample with
t >= t[i] + H, for H = 0.05, 0.2 and 0.5 s. Errors are wrapped to (-pi, pi]
and given in degrees: *end*, the error at that last sample; *traj*, the
errors at every sample after the start up to it. Each is summarised as a
root mean square over all starts (and samples), per joint and for both
joints pooled. The 6 records give 530 starts.

A model enters as ``predict(q0, qd0, t, tau) -> q``, batched over windows:
q0, qd0 (S, 2); t (S, K) sample times from the start sample; tau (S, K, 2);
returns q (S, K, 2). Windows shorter than K repeat their last time and torque
(intervals of zero length, in which no time passes).

**The models.**

- model_2.0: the publishers' identified parameters in their own plant
  (``D(q) q̈ + h(q, q̇) + V(q) + f(q̇) = u`` with the rotor's −n·Jr
  coupling and friction β q̇ + μ arctan(100 q̇)), integrated with RK4 in
  steps of at most 0.5 ms (:func:`plant_predictor`).
- model_2.0 without friction (β = μ = 0), and constant velocity.
- jaxrb: the committed scene ``examples/double_pendulum/fitted_double_pendulum.json``
  (two hinges, two motors of gear 1 driven by ``tau``), stepped through
  :func:`jaxrb.make_step` with ``dt`` set to each sample's interval
  (:func:`scene_predictor`).
- leave-one-record-out cross-validation of the fitting procedure
  (``examples/double_pendulum/fit.py``): each record scored by a model
  fitted on the other five, all records pooled; the honest held-out figure.

**Noise floor.** The start velocity is measured with noise of about
0.095 rad/s; adding that noise to qd[i] moves model_2.0's predictions by the
floor's amount (RMS over draws, :func:`noise_floor`). No model that starts
from the measured state can be expected to do much better.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import math
import os
import time
from typing import Callable, Optional, Sequence

import numpy as np

from jaxrb.bench.report import markdown_table

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
FOLDER = os.path.join(REPO, "examples", "double_pendulum")
DEFAULT_DATA = os.path.join(FOLDER, "double_pendulum.npz")
#: The committed model: ``python examples/double_pendulum/fit.py`` on all 6 records.
COMMITTED = os.path.join(FOLDER, "fitted_double_pendulum.json")
FIT_SCRIPT = os.path.join(FOLDER, "fit.py")

#: Prediction horizons (s) and the spacing of start points (s).
HORIZONS = (0.05, 0.2, 0.5)
START_SPACING = 0.1
#: Standard deviation of the measured joint velocities (rad/s), from the data's README.
VELOCITY_NOISE = 0.095
#: Longest RK4 step (s) of the publishers' plant; halving it changes the scores by < 1e-4°.
PLANT_STEP = 5e-4

#: The publishers' identified model, ``model_2.0_parameters.yml`` (yml keys).
MODEL_2_0 = dict(m1=0.5593806151425046, m2=0.6043459469186889, l1=0.3, r1=0.3, r2=0.18377686083653508,
                 I1=0.053470810264216295, I2=0.02392374528789766, Ir=7.659297952841183e-05, gr=6.0,
                 b1=0.001, b2=0.001, cf1=0.093, cf2=0.078, g=9.81)
#: The README's figures on these 6 records ("end both", degrees at 0.05, 0.2, 0.5 s).
README_END_BOTH = {"model_2.0": (0.40, 3.25, 15.53), "model_2.0 without friction": (0.67, 7.60, 27.17),
                   "constant velocity": (1.95, 26.41, 84.08), "noise floor": (0.26, 0.89, 2.1)}

FULL = dict(draws=20, cross_validation=True)
QUICK = dict(draws=4, cross_validation=False)


def data_path() -> str:
    """The data file: ``JAXRB_DOUBLE_PENDULUM`` if set, else the copy in ``examples/double_pendulum``."""
    return os.environ.get("JAXRB_DOUBLE_PENDULUM", DEFAULT_DATA)


# --------------------------------------------------------------------------- #
# Data and windows
# --------------------------------------------------------------------------- #

@dataclasses.dataclass(frozen=True)
class Record:
    """One record: times ``t`` (N,), angles ``q``, velocities ``qd``, measured and commanded torques (N, 2)."""

    name: str
    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    tau: np.ndarray
    tau_cmd: np.ndarray


def load_records(path: Optional[str] = None) -> list:
    """The records of ``double_pendulum.npz`` (format in ``examples/double_pendulum/DATA.md``).

    Args:
        path: the file; default :func:`data_path`.

    Returns:
        A list of :class:`Record`, named by their last path part (``trajectory_01``, ...).
    """
    with np.load(path or data_path()) as data:
        start = data["start"]
        return [Record(name=str(name).split("/")[-1],
                       **{key: np.asarray(data[key][start[k]:start[k + 1]], np.float64)
                          for key in ("t", "q", "qd", "tau", "tau_cmd")})
                for k, name in enumerate(data["record"])]


def wrap(angle):
    """Angles wrapped to (−π, π]."""
    wrapped = np.mod(np.asarray(angle) + np.pi, 2.0 * np.pi) - np.pi
    return np.where(wrapped == -np.pi, np.pi, wrapped)


def start_indices(t: np.ndarray, spacing: float = START_SPACING, longest: float = max(HORIZONS)) -> np.ndarray:
    """Start samples of one record: the first sample at or after each k·spacing, while t + longest ≤ t[-1]."""
    starts = []
    for k in range(int(t[-1] / spacing) + 2):
        i = int(np.searchsorted(t, k * spacing if spacing != 0.1 else k / 10.0, side="left"))
        if i >= len(t) or t[i] + longest > t[-1]:
            break
        starts.append(i)
    return np.asarray(starts, dtype=np.int64)


@dataclasses.dataclass(frozen=True)
class Window:
    """A scored window: record index, start sample, and the last sample of each horizon."""

    record: int
    start: int
    ends: dict


def windows(records: Sequence[Record], horizons: Sequence[float] = HORIZONS) -> list:
    """Every window of the protocol, record by record."""
    out = []
    for r, record in enumerate(records):
        for i in start_indices(record.t, longest=max(horizons)):
            ends = {h: int(np.searchsorted(record.t, record.t[i] + h, side="left")) for h in horizons}
            out.append(Window(record=r, start=int(i), ends=ends))
    return out


def window_batch(records: Sequence[Record], group: Sequence[Window]):
    """Padded inputs of ``group``: q0, qd0 (S, 2), t (S, K), tau (S, K, 2), and the lengths (S,).

    Each window runs from its start to its longest horizon's end, inclusive;
    shorter ones repeat their last time and torque.
    """
    longest = max(group[0].ends)
    lengths = np.array([w.ends[longest] - w.start + 1 for w in group])
    size, width = len(group), int(lengths.max())
    q0, qd0 = np.empty((size, 2)), np.empty((size, 2))
    t, tau = np.empty((size, width)), np.empty((size, width, 2))
    for s, (w, length) in enumerate(zip(group, lengths)):
        record, rows = records[w.record], slice(w.start, w.start + length)
        q0[s], qd0[s] = record.q[w.start], record.qd[w.start]
        t[s, :length], t[s, length:] = record.t[rows], record.t[w.start + length - 1]
        tau[s, :length], tau[s, length:] = record.tau[rows], record.tau[w.start + length - 1]
    return q0, qd0, t, tau, lengths


def predictions(predict: Callable, records: Sequence[Record], wins: Sequence[Window],
                velocity_noise=None) -> list:
    """Run ``predict`` on every window, one batch per record; returns per window q (length, 2).

    Args:
        velocity_noise: optional ``(S, 2) array -> (S, 2) array`` added to qd0 (the noise floor's draws).
    """
    out = [None] * len(wins)
    for r in range(len(records)):
        members = [s for s, w in enumerate(wins) if w.record == r]
        if not members:
            continue
        q0, qd0, t, tau, lengths = window_batch(records, [wins[s] for s in members])
        if velocity_noise is not None:
            qd0 = qd0 + velocity_noise(qd0.shape)
        q = np.asarray(predict(q0, qd0, t, tau))
        for k, s in enumerate(members):
            out[s] = q[k, :lengths[k]]
    return out


def _rms(x) -> float:
    return float(np.sqrt(np.mean(np.square(x)))) if np.size(x) else float("nan")


def score_predictions(records: Sequence[Record], wins: Sequence[Window], preds: Sequence[np.ndarray]) -> dict:
    """The protocol's summary of predictions (one (length, 2) array per window, from its start sample).

    Returns:
        ``{"starts": S, "end": {H: {"j1", "j2", "both"}}, "traj": {...},
        "per_record": {name: {H: end both}}}``, all in degrees.
    """
    out = {"starts": len(wins), "end": {}, "traj": {}, "per_record": {r.name: {} for r in records}}
    for h in HORIZONS:
        ends, trajectories = [], []
        for w, q in zip(wins, preds):
            stop = w.ends[h]
            error = np.degrees(wrap(q[1:stop - w.start + 1] - records[w.record].q[w.start + 1:stop + 1]))
            trajectories.append(error)
            ends.append(error[-1])
        ends, trajectory = np.asarray(ends), np.concatenate(trajectories)
        out["end"][h] = dict(j1=_rms(ends[:, 0]), j2=_rms(ends[:, 1]), both=_rms(ends))
        out["traj"][h] = dict(j1=_rms(trajectory[:, 0]), j2=_rms(trajectory[:, 1]), both=_rms(trajectory))
        owner = np.array([w.record for w in wins])
        for r, record in enumerate(records):
            out["per_record"][record.name][h] = _rms(ends[owner == r])
    return out


def score(predict: Callable, records: Sequence[Record]) -> dict:
    """Score ``predict`` (module docstring) on ``records`` by the protocol (:func:`score_predictions`)."""
    wins = windows(records)
    return score_predictions(records, wins, predictions(predict, records, wins))


def end_both(result: dict) -> tuple:
    """(end both at 0.05, 0.2, 0.5 s) of a :func:`score` result."""
    return tuple(result["end"][h]["both"] for h in HORIZONS)


def constant_velocity(q0, qd0, t, tau):
    """q[i] + qd[i]·(t − t[i])."""
    return q0[:, None, :] + qd0[:, None, :] * (t - t[:, :1])[:, :, None]


# --------------------------------------------------------------------------- #
# The publishers' plant
# --------------------------------------------------------------------------- #

def plant_predictor(values: dict = MODEL_2_0, friction: bool = True, coupling: bool = True,
                    step: float = PLANT_STEP) -> Callable:
    """The publishers' plant (the data's README, "The publishers' plant") as a batched ``predict``.

    D(θ) ω̇ + h(θ, ω) + V(θ) + f(ω) = u with, in yml symbols (J = I about the
    joint, a = r, L1 = l1, n = gr, β = b, μ = cf):

        D11 = J1 + J2 + m2 L1² + 2 m2 L1 a2 cos θ2 + (n² + 1) Jr
        D12 = J2 + m2 L1 a2 cos θ2 − n Jr        D22 = J2 + n² Jr
        h1 = −m2 L1 a2 sin θ2 (2 ω1 ω2 + ω2²)    h2 = m2 L1 a2 sin θ2 ω1²
        V1 = g (m1 a1 + m2 L1) sin θ1 + g m2 a2 sin(θ1 + θ2)    V2 = g m2 a2 sin(θ1 + θ2)
        fi = βi ωi + μi arctan(100 ωi)

    Each sample interval is split into ceil(dt / step) equal RK4 steps, the
    torque held; zero-length intervals are skipped.

    Args:
        values: yml keys as :data:`MODEL_2_0`.
        friction: False sets β = μ = 0.
        coupling: False drops the −n Jr term of D12 (a diagonal armature's plant).
        step: the longest RK4 step (s).
    """
    v = values
    length, n, g = v["l1"], v["gr"], v["g"]
    inertia1, inertia2, rotor = v["I1"] + v["m2"] * length ** 2, v["I2"], v["Ir"]
    arm2, arm1 = v["m2"] * v["r2"], v["m1"] * v["r1"] + v["m2"] * length
    damping = np.array([v["b1"], v["b2"]]) if friction else np.zeros(2)
    coulomb = np.array([v["cf1"], v["cf2"]]) if friction else np.zeros(2)
    off_diagonal_rotor = n * rotor if coupling else 0.0

    def acceleration(q, w, u):
        cos2, sin2 = np.cos(q[:, 1]), np.sin(q[:, 1])
        coupling_term = length * arm2 * cos2
        d11 = inertia1 + inertia2 + 2 * coupling_term + (n * n + 1) * rotor
        d12 = inertia2 + coupling_term - off_diagonal_rotor
        d22 = inertia2 + n * n * rotor
        gravity2 = g * arm2 * np.sin(q[:, 0] + q[:, 1])
        force = u - damping * w - coulomb * np.arctan(100.0 * w)
        r1 = force[:, 0] + length * arm2 * sin2 * (2 * w[:, 0] * w[:, 1] + w[:, 1] ** 2) \
            - g * arm1 * np.sin(q[:, 0]) - gravity2
        r2 = force[:, 1] - length * arm2 * sin2 * w[:, 0] ** 2 - gravity2
        det = d11 * d22 - d12 * d12
        return np.stack([(d22 * r1 - d12 * r2) / det, (d11 * r2 - d12 * r1) / det], axis=1)

    def rk4(q, w, h, u):
        h = h[:, None]
        a1 = acceleration(q, w, u)
        a2 = acceleration(q + 0.5 * h * w, w + 0.5 * h * a1, u)
        a3 = acceleration(q + 0.5 * h * (w + 0.5 * h * a1), w + 0.5 * h * a2, u)
        a4 = acceleration(q + h * (w + 0.5 * h * a2), w + h * a3, u)
        q_new = q + h / 6.0 * (w + 2 * (w + 0.5 * h * a1) + 2 * (w + 0.5 * h * a2) + (w + h * a3))
        return q_new, w + h / 6.0 * (a1 + 2 * a2 + 2 * a3 + a4)

    def predict(q0, qd0, t, tau):
        q, w = np.array(q0, np.float64), np.array(qd0, np.float64)
        out = np.empty(t.shape + (2,))
        out[:, 0] = q
        intervals = np.diff(t, axis=1)
        counts = np.maximum(np.ceil(intervals / step - 1e-12), 1).astype(int)
        for k in range(intervals.shape[1]):
            h = intervals[:, k] / counts[:, k]
            for sub in range(int(counts[:, k].max())):
                q, w = rk4(q, w, np.where(sub < counts[:, k], h, 0.0), tau[:, k])
            out[:, k + 1] = q
        return out

    return predict


# --------------------------------------------------------------------------- #
# jaxrb scenes
# --------------------------------------------------------------------------- #

def scene_rollout(model, state):
    """``(params, q0 (2,), qd0 (2,), dt (K-1,), tau (K-1, 2)) -> q (K, 2)``: one window through jaxrb's step.

    The step runs once per sample interval with ``params.dt`` set to it and
    the controls set to that sample's torque; the State starts from
    ``rb.joints.set_qpos_qvel``. Intervals of zero length (padding) leave the
    state as it is. Traceable: vmap it over windows, differentiate it.
    """
    import jax
    import jax.numpy as jnp

    import jaxrb as rb

    step = rb.make_step(model)

    def rollout(params, q0, qd0, dt, tau):
        start = rb.joints.set_qpos_qvel(model, params, state, q0, qd0)

        def one(current, interval):
            h, controls = interval
            # A zero-length (padded) interval is no step at all, whatever the integrator; the step itself
            # runs at the nominal dt there, as RK4 would divide by a zero dt.
            positive = h > 0
            stepped = step(current, params.replace(dt=jnp.where(positive, h, params.dt)), None, controls)
            current = jax.tree_util.tree_map(lambda new, old: jnp.where(positive, new, old), stepped, current)
            return current, current.qpos

        _, q = jax.lax.scan(one, start, (dt, tau))
        return jnp.concatenate([jnp.asarray(q0, q.dtype)[None], q])

    return rollout


def scene_predictor(model, params, state) -> Callable:
    """A built jaxrb scene (two hinges, two motors) as a batched ``predict`` (jit, vmap over windows)."""
    import jax
    import jax.numpy as jnp

    rollout = jax.jit(jax.vmap(scene_rollout(model, state), in_axes=(None, 0, 0, 0, 0)))
    dtype = params.mass.dtype

    def predict(q0, qd0, t, tau):
        arrays = (q0, qd0, np.diff(t, axis=1), tau[:, :-1])
        return np.asarray(rollout(params, *(jnp.asarray(a, dtype) for a in arrays)))

    return predict


def load_fitted(path: str = COMMITTED):
    """``(model, params, state)`` of a scene file, built in float64 with its stored build options."""
    import jax

    import jaxrb as rb

    jax.config.update("jax_enable_x64", True)
    return rb.load_scene(path).build(dtype="float64")


def load_fit_script():
    """``examples/double_pendulum/fit.py`` as a module (the fitting procedure the cross-validation runs)."""
    import sys

    name = "double_pendulum_fit"
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, FIT_SCRIPT)
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module  # before running it: its dataclasses look their module up
        spec.loader.exec_module(module)
    return sys.modules[name]


# --------------------------------------------------------------------------- #
# Noise floor and cross-validation
# --------------------------------------------------------------------------- #

def noise_floor(predict: Callable, records: Sequence[Record], draws: int = 20, seed: int = 0,
                noise: float = VELOCITY_NOISE) -> dict:
    """How far velocity noise alone moves ``predict``'s end predictions (degrees, both joints pooled).

    Each draw adds N(0, noise²) to every start velocity; the RMS change of
    the end prediction is pooled over starts and draws.

    Returns:
        ``{"pooled": (per horizon), "low": ..., "high": ...}``: the pooled
        RMS and the smallest and largest single draw.
    """
    wins = windows(records)
    base = predictions(predict, records, wins)
    rng = np.random.default_rng(seed)
    per_draw = []
    for _ in range(draws):
        moved = predictions(predict, records, wins, velocity_noise=lambda shape: rng.normal(0.0, noise, shape))
        per_draw.append([_rms([np.degrees(wrap(m[w.ends[h] - w.start] - b[w.ends[h] - w.start]))
                               for w, m, b in zip(wins, moved, base)]) for h in HORIZONS])
    per_draw = np.asarray(per_draw)
    return {"pooled": tuple(np.sqrt(np.mean(per_draw ** 2, axis=0))), "low": tuple(per_draw.min(axis=0)),
            "high": tuple(per_draw.max(axis=0))}


def cross_validate(records: Sequence[Record], fit_module=None, log=print) -> dict:
    """Leave-one-record-out: each record predicted by the fitting procedure run on the other five.

    Returns:
        ``{"score": pooled protocol result, "values": [per fold fitted values],
        "seconds": total}``.
    """
    fit_module = fit_module or load_fit_script()
    wins = windows(records)
    preds = [None] * len(wins)
    folds, clock = [], time.perf_counter()
    for r, record in enumerate(records):
        log(f"double_pendulum: cross-validation, fitting without {record.name}")
        fitted = fit_module.fit(records, leave_out=r, log=lambda line: None)
        predict = fit_module.predictor(fitted.values)
        own = [s for s, w in enumerate(wins) if w.record == r]
        for s, q in zip(own, predictions(predict, records, [wins[s] for s in own])):
            preds[s] = q
        folds.append(fitted.values)
    return {"score": score_predictions(records, wins, preds), "values": folds,
            "seconds": time.perf_counter() - clock}


# --------------------------------------------------------------------------- #
# The report section
# --------------------------------------------------------------------------- #

def combinations(params) -> dict:
    """The identifiable combinations of a built double-pendulum scene (examples/double_pendulum/fit.py's KEYS).

    Reads link 1's and link 2's masses, centres of mass (their distance from
    the joint), y inertias, the elbow's offset L1 and the joints' armature
    (Jr = armature₂ / 36, gear 6), damping and friction.
    """
    mass, inertia = np.asarray(params.mass), np.asarray(params.inertia)[:, 1, 1]
    arm = np.linalg.norm(np.asarray(params.com_offset), axis=1)
    length = float(np.linalg.norm(np.asarray(params.parent_offset)[1]))
    damping, friction = np.asarray(params.joint_damping), np.asarray(params.joint_frictionloss)
    return dict(Th1=float(inertia[0] + mass[0] * arm[0] ** 2 + mass[1] * length ** 2),
                J2=float(inertia[1] + mass[1] * arm[1] ** 2), m2a2=float(mass[1] * arm[1]),
                ga=float(mass[0] * arm[0] + mass[1] * length), Jr=float(np.asarray(params.joint_armature)[1] / 36.0),
                b1=float(damping[0]), b2=float(damping[1]), mu1=float(friction[0]), mu2=float(friction[1]))


def published_combinations(values: dict = MODEL_2_0) -> dict:
    """model_2.0's combinations; its Coulomb μ as (π/2)·cf, the level its arctan law reaches at speed."""
    v = values
    return dict(Th1=v["I1"] + v["m2"] * v["l1"] ** 2, J2=v["I2"], m2a2=v["m2"] * v["r2"],
                ga=v["m1"] * v["r1"] + v["m2"] * v["l1"], Jr=v["Ir"], b1=v["b1"], b2=v["b2"],
                mu1=math.pi / 2 * v["cf1"], mu2=math.pi / 2 * v["cf2"])


def _fmt(values) -> str:
    return " / ".join(f"{x:.2f}" for x in values)


def double_pendulum_section(settings: dict, log=print):
    """Run the section; return ``(markdown, results)``.

    ``settings``: ``draws`` (noise-floor draws) and ``cross_validation``
    (also run the fitting procedure: on all 6 records, for the fitted
    values' uncertainty and the fit's time, and leave-one-record-out).
    """
    path = data_path()
    if not os.path.exists(path):
        return f"Skipped: no double-pendulum data at `{path}` (set JAXRB_DOUBLE_PENDULUM).", {}
    records = load_records(path)
    results, scored = {}, {}
    rows = []

    def add(name, result, seconds=None):
        scored[name] = result
        results[name] = dict(end_both=end_both(result), seconds=seconds,
                             per_record={k: tuple(v.values()) for k, v in result["per_record"].items()})
        rows.append([name] + [f"{result['end'][h]['both']:.2f}" for h in HORIZONS]
                    + [f"{result['traj'][h]['both']:.2f}" for h in HORIZONS]
                    + [f"{result['end'][0.5]['j1']:.2f} / {result['end'][0.5]['j2']:.2f}",
                       "—" if seconds is None else f"{seconds:.2f} s"])
        log(f"double_pendulum: {name}: end both {_fmt(end_both(result))}")

    def timed(name, predict):
        clock = time.perf_counter()
        result = score(predict, records)
        add(name, result, time.perf_counter() - clock)

    published = plant_predictor(MODEL_2_0)
    timed("model_2.0 (publishers' plant, RK4 ≤ 0.5 ms)", published)
    timed("model_2.0 without friction (β = μ = 0)", plant_predictor(MODEL_2_0, friction=False))
    timed("constant velocity", constant_velocity)
    fitted = None
    if os.path.exists(COMMITTED):
        model, params, state = load_fitted(COMMITTED)
        fitted = combinations(params)
        predict = scene_predictor(model, params, state)
        clock = time.perf_counter()
        score(predict, records)  # compiles one program per record's window shape
        results["jaxrb_compile_seconds"] = time.perf_counter() - clock
        timed("jaxrb, `fitted_double_pendulum.json` (fitted on these 6: in-sample)", predict)
    fit = None
    if settings["cross_validation"]:
        fit_module = load_fit_script()
        log("double_pendulum: fitting on all 6 records")
        fit = fit_module.fit(records, log=lambda line: log("  " + line))
        cv = cross_validate(records, fit_module, log)
        add("jaxrb, leave-one-record-out (each record by a fit on the other 5)", cv["score"], cv["seconds"])
        results["cross_validation_values"] = cv["values"]
        results["fit"] = dict(values=fit.values, standard_errors=fit.standard_errors, seconds=fit.seconds,
                              iterations=fit.iterations)
    floor = noise_floor(published, records, draws=settings["draws"])
    results["noise_floor"] = floor
    rows.append([f"noise floor (model_2.0, qd[i] + N(0, {VELOCITY_NOISE}²), {settings['draws']} draws)"]
                + [f"{x:.2f}" for x in floor["pooled"]] + ["", "", "", "", ""])

    lines = [f"Data: `{os.path.relpath(path, REPO)}`, {len(records)} records of a real double pendulum (DFKI), "
             f"{len(windows(records))} starts. Joint-angle errors (degrees, RMS over starts, both joints pooled) of "
             "predictions from the measured state driven by the measured torques, by the data README's protocol. "
             "*end*: at the horizon; *traj*: every sample up to it. jaxrb steps its scene once per sample "
             "interval (dt set to it, that sample's torque as the motors' controls).", "",
             markdown_table(["model", "end 0.05 s", "end 0.2 s", "end 0.5 s", "traj 0.05 s", "traj 0.2 s",
                             "traj 0.5 s", "end 0.5 s j1 / j2", "time (530 starts)"], rows), "",
             "End both by record (0.05 / 0.2 / 0.5 s):", ""]
    names = list(scored)
    lines.append(markdown_table(["record"] + [n.split(" (")[0].split(",")[0] + (", LORO" if "leave" in n else "")
                                              for n in names],
                                [[record.name] + [_fmt(scored[n]["per_record"][record.name].values()) for n in names]
                                 for record in records]))
    published_values = published_combinations()
    if fitted is not None:
        header = ["combination", "model_2.0", "`fitted_double_pendulum.json`"]
        table = []
        for key in published_values:
            row = [key, f"{published_values[key]:.4g}", f"{fitted[key]:.4g}"]
            if fit is not None:
                row.append(f"{fit.values[key]:.4g} ± {fit.standard_errors[key]:.2g}")
                spread = np.array([v[key] for v in results["cross_validation_values"]])
                row.append(f"{np.sqrt((len(spread) - 1) / len(spread) * np.sum((spread - spread.mean()) ** 2)):.2g}")
            table.append(row)
        if fit is not None:
            header += ["refit here ± sandwich SE", "leave-one-out jackknife SE"]
        lines += ["", "The identified combinations (Th1 = J1 + m2 L1², ga = m1 a1 + m2 L1, kg and m; Jr the rotor; "
                  "b N m s; μ N m, model_2.0's as (π/2)·cf):", "", markdown_table(header, table)]
        if fit is not None:
            lines += ["", f"Fit on all 6 records: {fit.seconds:.1f} s on this machine, compile included "
                      f"({fit.iterations} Levenberg–Marquardt iterations). The sandwich errors take 1 s blocks as "
                      "independent; the jackknife's, from the six leave-one-out fits, also carry the differences "
                      "between records and are the ones to quote."]
    ours = results.get("jaxrb, leave-one-record-out (each record by a fit on the other 5)")
    if ours is not None:
        theirs = results["model_2.0 (publishers' plant, RK4 ≤ 0.5 ms)"]["end_both"]
        mine = ours["end_both"]
        required = mine[1] < theirs[1] and mine[2] < theirs[2] and mine[0] <= 1.05 * theirs[0]
        goal = all(mine[k] <= 1.2 * floor["pooled"][k] for k in (1, 2))
        lines += ["", f"Held out (leave-one-record-out) against model_2.0 (which saw these records): "
                  f"{_fmt(mine)} against {_fmt(theirs)}: requirement (better at 0.2 and 0.5 s, within 5 % at "
                  f"0.05 s) **{'PASS' if required else 'MISSED'}**; goal (within 1.2× the noise floor at 0.2 and "
                  f"0.5 s: {1.2 * floor['pooled'][1]:.2f}, {1.2 * floor['pooled'][2]:.2f}) "
                  f"**{'PASS' if goal else 'MISSED'}**."]
    lines += ["", f"Noise floor: single draws range {floor['low'][1]:.2f}–{floor['high'][1]:.2f}° at 0.2 s and "
              f"{floor['low'][2]:.2f}–{floor['high'][2]:.2f}° at 0.5 s."]
    if "jaxrb_compile_seconds" in results:
        lines += ["", "Times are for scoring all 530 starts on this machine (numpy RK4 for the plant; jaxrb jitted "
                  f"and vmapped over each record's starts, after {results['jaxrb_compile_seconds']:.1f} s of "
                  "compiling)."]
    return "\n".join(lines), results
