"""Peers side by side: jaxrb against MuJoCo (C), MJX, Brax and Jax2D in one run.

Every peer is optional: it is imported inside ``try`` and a peer that is absent
or fails is skipped with a note saying why (``pip install -e ".[peers]"``
brings them in). The scenes are the ones jaxrb's own benchmarks use
(:mod:`jaxrb.bench.contact`, :mod:`jaxrb.bench.free_body`); the peers get the
same bodies, built here as MJCF strings (MuJoCo, MJX, Brax) or with the
peer's own scene API (Jax2D, pymunk):

* **drop**: a 0.2 m box (1 kg) released with its centre at 0.5 m above a
  plane, friction 0.5. Peers step at h = 2 ms; jaxrb runs its own best setting
  (impulse contact, dt = 1/60 s, 4 substeps) *and* h = 2 ms (1 substep) with
  impulse and with penalty contact (:data:`DROP_JAXRB`).
  Figures: body-steps/s at a batch of worlds, compile time, and the resting
  height z − 0.1 m after the rollout (mean over worlds; its largest
  magnitude is what the target checks).
* **stack**: 10 boxes in a column on the plane for ``peers_stack_seconds``;
  *sink* = how far the top box ends below its height with every box
  exactly touching (mean over worlds; a batched world starts lifted by
  0–1 mm, which is not sinking), *drift* = horizontal displacement of the
  top box at the end (largest over worlds). jaxrb runs it with impulse
  contact at dt = 1/60 s with 8 substeps and a 12-pair broadphase
  (:data:`STACK_BUILD`), and with penalty contact at h = 0.5 ms with the
  spring of :data:`STACK_PENALTY_FREQUENCY` (:data:`STANDING_SETTINGS`; the
  same broadphase). Every engine starts from the same column, each box set
  off sideways by up to 1 mm (:func:`jaxrb.bench.contact.column_centres`).
* **pyramid**: the 55-box 2D pyramid (10 rows, 5 % gaps, μ = 0.5), jaxrb
  against Jax2D at the same batch and pymunk in one world; *stands* = the top
  box moved less than 1 cm sideways and sank less than half a box (and, for
  jaxrb, its broadphase never ran out of pairs). jaxrb runs it with impulse
  contact at its own setting and with penalty contact at h = 2 ms, both with
  a 150-pair broadphase (:data:`PYRAMID_BUILD`); the peers step at 1/60 s
  (body-s/s compares across step sizes).

  Every jaxrb setting of a scene is a row of its own and is checked against
  every target of the scene (:func:`evaluate_targets`).
* **flip**: the torque-free intermediate-axis flip (inertia (0.3, 0.35,
  0.4) kg m², ω0 = (0.1, 15, 0.1) rad/s): largest flip-time error against
  :func:`jaxrb.analytic.flip_times` for MuJoCo C's RK4 (float64), MJX's RK4
  (float32) and jaxrb's best integrator (float32 and float64) at each h.
* **gradient**: the drop's gradient in one world (and, against Brax spring,
  in a batch of worlds), jaxrb against the peers
  that differentiate (MJX, Brax): forward and gradient time, whether every
  entry is finite, and the loss (:mod:`benchmarks.peer_gradients`).

Timing is :func:`jaxrb.bench.timing.time_jitted` for everything jitted
(compile apart, then the median of calls after a warm-up, with
``block_until_ready``); MuJoCo C is timed with ``time.perf_counter`` around
``mj_step`` calls from Python (one world) and around ``mujoco.rollout`` (a
loop over worlds in C, one thread). Peers' JAX code runs with x64 disabled
so that they compute in float32 like jaxrb's throughput runs.

Where ``import jaxrb`` set LLVM's unroll limit (:data:`jaxrb.compile.UNROLL_LIMIT_OPTION`),
each scene's peers run in a child process whose ``XLA_FLAGS`` are this
process's without it (:func:`peer_process_flags`): LLVM options hold for a
whole process, and the limit slowed Brax spring's batched drop by about 6 %
(docs/performance.md, section 47). jaxrb's rows of the scene run here first,
then the child's; the loop threshold stays in both, as in the reports before.

Settings (:data:`QUICK`, :data:`FULL`; every key starts with ``peers_``):
``scenes`` and ``engines`` to run; ``drop_batch``/``drop_steps`` and
``drop_jaxrb`` (jaxrb's (contact, dt, substeps) settings); ``mujoco_worlds`` (worlds in
MuJoCo's C rollout loop); ``stack_batch``/``stack_seconds``/``stack_mjx`` and
``stack_jaxrb`` (jaxrb's contact models, see :data:`STANDING_SETTINGS`);
``pyramid_batch``/``pyramid_seconds``/``pyramid_big_batch`` (jaxrb also at
this batch, for the pymunk target; ``None`` to skip), ``pyramid_big_seconds``
and ``pyramid_jaxrb``; ``flip_steps``,
``flip_horizon`` and ``flip_configs`` (jaxrb (integrator, orientation) pairs;
the best per h counts), ``flip_mjx`` (False: MJX's flip skipped);
``gradient_steps`` (T), ``gradient_rounds`` (timed rounds at most) and
``gradient_batch`` (worlds of the batched rows; ``None`` to skip);
``repeats``/``budget_s`` for timing; ``with_jaxrb``
(False: peers only).

Installed together (checked with ``pip check``) on Python 3.11 with jax and
jaxlib 0.10.2: brax 0.14.2 (flax 0.12.8), mujoco 4.0.0, mujoco-mjx 3.17.0,
jax2d 1.0.2 (which imports chex without declaring it: chex 0.1.92) and
pymunk 7.3.1.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import os
import pickle
import statistics
import subprocess
import sys
import tempfile
import time
from typing import Callable, Dict, List, Optional, Sequence, Tuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxrb import analytic
from jaxrb import compile as rb_compile
from jaxrb.bench import contact, free_body
from jaxrb.bench.report import fmt_fixed, fmt_sci, fmt_si, fmt_step, markdown_table
from jaxrb.bench.timing import final_state_fn, time_jitted

HALF = contact.HALF  # m, half edge of every box
DROP_CENTRE = contact.DROP_CENTRE
PEER_STEP = 0.002  # s, the peers' step in the 3D contact scenes
JAXRB_BEST = dict(dt=1 / 60, substeps=4)  # jaxrb's own setting for contact scenes
#: The 10-box column: 8 substeps, because at 4 the soft contacts sink 6.5 mm
#: (the target is < 2 mm; 8 gives 1.5 mm). Its near
#: pairs are its 9 neighbours: a bounding-sphere broadphase keeping 12 pairs
#: gives the solver 176 rows instead of all pairs' 440.
STACK_BUILD = dict(substeps=8, broadphase="spheres", broadphase_capacity=12)
#: The pyramid's broadphase: 135 box pairs are near (bounding spheres) while it
#: stands; 150 leaves 15 to spare (the default, 4 per body, is 220, and the
#: narrowphase work grows with it: penalty at batch 256 ran 0.81 M body-steps/s
#: with 220, 1.1 M with 150). An overflow is reported and fails "stands".
PYRAMID_BUILD = dict(broadphase="spheres", broadphase_capacity=150)
FRICTION = 0.5
STACK_COUNT = 10
PYRAMID_ROWS = 10
PYRAMID_TOP = PYRAMID_ROWS * (PYRAMID_ROWS + 1) // 2 - 1  # bodies are added row by row
STACK_TOP_REST = HALF * (2 * STACK_COUNT - 1)  # m, the top box's centre with every box touching
STAND_DRIFT = 0.01  # m, largest sideways move of the pyramid's top box that still "stands"
STAND_SINK = HALF  # m, largest fall (or rise) of the top box that still "stands" (half a box)
PYMUNK_TARGET_BATCH = 256  # worlds at which jaxrb's pyramid must outrun pymunk's one world

#: Every peer this module knows, in report order.
ENGINES = ("mujoco", "mjx", "brax_spring", "brax_positional", "jax2d", "pymunk")
ENGINE_NAMES = {"jaxrb": "jaxrb", "mujoco": "MuJoCo C", "mjx": "MJX", "brax_spring": "Brax spring",
                "brax_positional": "Brax positional", "jax2d": "Jax2D", "pymunk": "pymunk"}
SCENE_TITLES = {"drop": "Box drop", "stack": "10-box stack", "pyramid": "2D 10-row pyramid (55 boxes)",
                "flip": "Torque-free flip", "gradient": "Gradient through contact"}

#: jaxrb's box-drop rows: (contact model, dt, substeps). Its own impulse setting, and
#: both contact models at the peers' h = 2 ms (penalty being what Brax spring is).
DROP_JAXRB = (("impulse", JAXRB_BEST["dt"], JAXRB_BEST["substeps"]), ("impulse", PEER_STEP, 1),
              ("penalty", PEER_STEP, 1))
#: The penalty column's step and spring: 42.4 Hz, twice the stiffness of the
#: default (0.03/h Hz) at h = 1 ms, stepped at h = 0.5 ms. From the aligned
#: column (batch 16, 5 s) the default spring sank 11 mm at h = 2 ms and 3.2 mm
#: at 1 ms, this one 1.6 mm at 1 ms. But from a column whose boxes are set off
#: sideways by up to 1 mm (contact.column_centres, 8 worlds of other offsets),
#: at h = 1 ms this spring's top box drifted 2–24 mm in 1 s and the default's up
#: to 5 mm from 0.1 mm offsets: the explicit spring is too fast for the rocking
#: of a box on its corners. At h = 0.5 ms it drifted ≤ 0.09 mm and sank
#: ≤ 1.66 mm over 5 s; twice this stiffness at 0.5 ms drifted 36 mm. Those
#: figures counted the bottom pair four times (a broadphase bug, fixed in
#: bc4616e); counted once it sinks 1.90 mm and drifts 0.21 mm
#: (docs/performance.md section 15).
STACK_PENALTY_STEP = 5e-4  # s
STACK_PENALTY_FREQUENCY = 0.03 * math.sqrt(2.0) / 1e-3  # Hz
#: jaxrb's settings for the standing scenes, by contact model and scene: (dt,
#: substeps, extra Scene.build options). Impulse at its own setting. Penalty at
#: the peers' h = 2 ms for the pyramid; the column needs a quarter of that
#: step and the stiffer spring above to sink < 2 mm and keep still (its
#: body-s/s column says what the smaller step costs).
STANDING_SETTINGS = {
    "impulse": {"stack": (JAXRB_BEST["dt"], JAXRB_BEST["substeps"], STACK_BUILD),
                "pyramid": (JAXRB_BEST["dt"], JAXRB_BEST["substeps"], PYRAMID_BUILD)},
    "penalty": {"stack": (STACK_PENALTY_STEP, 1, dict(STACK_BUILD, contact="penalty", substeps=1,
                                        penalty_frequency=STACK_PENALTY_FREQUENCY)),
                "pyramid": (PEER_STEP, 1, dict(PYRAMID_BUILD, contact="penalty"))},
}

#: QUICK runs the box drop (jaxrb's penalty row against MuJoCo C, MJX and Brax
#: spring, the peers of its targets) and the flip at one h (jaxrb's RK4s against
#: MuJoCo C); the stack, the pyramid, the gradient, Brax positional, Jax2D, pymunk
#: and MJX's flip are in the full run only. Compiling is most of the section's time: the
#: peers' programs alone compile for 8-24 s each (Brax positional's drop 24 s,
#: Jax2D's pyramid 21 s, Brax spring's stack 15 s), and with all four scenes
#: the quick section took 161 s on the 2-core host.
QUICK = dict(
    peers_scenes=("drop", "flip"), peers_engines=("mujoco", "mjx", "brax_spring"),
    peers_drop_batch=64, peers_drop_steps=500, peers_mujoco_worlds=16,
    peers_drop_jaxrb=tuple(row for row in DROP_JAXRB if row[0] == "penalty"),
    peers_stack_batch=4, peers_stack_seconds=1.0, peers_stack_mjx=False,
    peers_stack_jaxrb=("penalty",),
    peers_pyramid_batch=4, peers_pyramid_seconds=1.0, peers_pyramid_big_batch=None,
    peers_pyramid_big_seconds=1.0, peers_pyramid_jaxrb=("penalty",),
    peers_flip_steps=(1 / 60,), peers_flip_horizon=6.0,
    peers_flip_configs=(("rk4", None), ("rk4_body", None)), peers_flip_mjx=False,
    peers_repeats=2, peers_budget_s=3.0, peers_with_jaxrb=True,
)
FULL = dict(
    peers_scenes=("drop", "stack", "pyramid", "flip", "gradient"), peers_engines=ENGINES,
    peers_drop_batch=1024, peers_drop_steps=1000, peers_mujoco_worlds=256,
    peers_drop_jaxrb=DROP_JAXRB,
    peers_stack_batch=16, peers_stack_seconds=5.0, peers_stack_mjx=False,  # MJX: ~1.5 k body-steps/s, 4+ min
    peers_stack_jaxrb=("impulse", "penalty"),
    peers_pyramid_batch=16, peers_pyramid_seconds=5.0, peers_pyramid_big_batch=PYMUNK_TARGET_BATCH,
    peers_pyramid_big_seconds=1.0,  # the batch-256 run is for speed; standing is judged at peers_pyramid_batch
    peers_pyramid_jaxrb=("impulse", "penalty"),
    peers_flip_steps=(1 / 60, 1 / 240, 1 / 1000), peers_flip_horizon=20.0,
    peers_flip_configs=(("rk4", None), ("rk4_body", None), ("implicit_gyro", "exp_map")), peers_flip_mjx=True,
    peers_gradient_steps=1000, peers_gradient_rounds=101,  # rounds stop once peers_budget_s is spent
    peers_gradient_batch=1024,
    peers_repeats=3, peers_budget_s=5.0, peers_with_jaxrb=True,
)


# --- results --------------------------------------------------------------------------------

@dataclasses.dataclass
class PeerRow:
    """One engine on one scene in one setting.

    Attributes:
        scene: ``"drop"``, ``"stack"``, ``"pyramid"`` or ``"flip"``.
        engine: ``"jaxrb"`` or a key of :data:`ENGINES`.
        setting: short text, e.g. ``"impulse, 1/60 s × 4"``.
        h: step (s); a jaxrb step includes its substeps.
        batch: worlds per call (1: one world).
        num_bodies: moving bodies per world.
        num_steps: steps per call.
        compile_s: trace + lower + compile (s); ``None`` for compiled C code.
        run_s: median wall seconds of one call.
        metrics: scene figures: ``rest_offset``/``rest_error`` (m), ``sink``/``drift`` (m),
            ``stands`` (bool), ``flip_error`` (s), ``flips`` (text), ``dtype``.
    """

    scene: str
    engine: str
    setting: str
    h: float
    batch: int
    num_bodies: int
    num_steps: int
    compile_s: Optional[float]
    run_s: float
    metrics: dict = dataclasses.field(default_factory=dict)

    @property
    def body_steps_per_s(self) -> float:
        return self.batch * self.num_bodies * self.num_steps / self.run_s if self.run_s > 0 else math.nan

    @property
    def label(self) -> str:
        return f"{ENGINE_NAMES.get(self.engine, self.engine)} ({self.setting}, batch {self.batch})"


@dataclasses.dataclass
class Target:
    """One target (issues 6 and 60): what was measured and whether it was met (``None``: not measured)."""

    scene: str
    text: str
    measured: str
    ok: Optional[bool]

    @property
    def status(self) -> str:
        return "NOT MEASURED" if self.ok is None else ("PASS" if self.ok else "MISSED")


def ratio(numerator: Optional[float], denominator: Optional[float]) -> float:
    """``numerator / denominator``; nan when either is missing, non-finite or the denominator ≤ 0.

    Args:
        numerator: scalar, e.g. jaxrb's body-steps/s.
        denominator: scalar, e.g. a peer's body-steps/s.

    Returns:
        The ratio as a float.
    """
    if numerator is None or denominator is None:
        return math.nan
    numerator, denominator = float(numerator), float(denominator)
    if not (math.isfinite(numerator) and math.isfinite(denominator)) or denominator <= 0.0:
        return math.nan
    return numerator / denominator


# --- small helpers --------------------------------------------------------------------------

@contextlib.contextmanager
def x64(enabled: bool):
    """Run a block with ``jax_enable_x64`` set to ``enabled`` and restore it afterwards.

    Args:
        enabled: True for float64 by default, False for float32.

    Yields:
        Nothing.
    """
    previous = bool(jax.config.jax_enable_x64)
    jax.config.update("jax_enable_x64", enabled)
    try:
        yield
    finally:
        jax.config.update("jax_enable_x64", previous)


def world_shifts(batch: int, dim: int, seed: int = 1) -> np.ndarray:
    """Per-world offsets of every body, the same draws as :mod:`jaxrb.bench.contact` uses.

    Args:
        batch: number of worlds.
        dim: 2 or 3.
        seed: NumPy generator seed.

    Returns:
        (batch, dim) offsets (m): ±1 mm along the ground, 0–1 mm up.
    """
    rng = np.random.default_rng(seed)
    return np.concatenate([rng.uniform(-1e-3, 1e-3, size=(batch, dim - 1)),
                           rng.uniform(0.0, 1e-3, size=(batch, 1))], axis=1)


def _free_qpos(qpos0: np.ndarray, num_bodies: int, shifts: np.ndarray) -> np.ndarray:
    """(batch, 7·n) free-joint positions: ``qpos0`` with each world's shift added to every body."""
    batch = shifts.shape[0]
    qpos = np.tile(np.asarray(qpos0, dtype=np.float64), (batch, 1))
    for body in range(num_bodies):
        qpos[:, 7 * body:7 * body + 3] += shifts
    return qpos


def boxes_mjcf(centres: Sequence[Sequence[float]], h: float, integrator: str = "Euler") -> str:
    """MJCF of 0.2 m boxes (1 kg, μ = 0.5) with free joints above a ground plane.

    Args:
        centres: (n, 3) initial box centres (m).
        h: time step (s).
        integrator: MuJoCo integrator name.

    Returns:
        The model as an XML string.
    """
    bodies = "\n".join(
        f'    <body name="box{i}" pos="{x:.17g} {y:.17g} {z:.17g}"><freejoint/>'
        f'<geom type="box" size="{HALF} {HALF} {HALF}" mass="1" friction="{FRICTION}"/></body>'
        for i, (x, y, z) in enumerate(centres))
    return (f'<mujoco model="jaxrb_peer_boxes">\n'
            f'  <option timestep="{h!r}" gravity="0 0 -9.81" integrator="{integrator}"/>\n'
            f'  <worldbody>\n'
            f'    <geom name="ground" type="plane" size="5 5 0.1" friction="{FRICTION}"/>\n'
            f'{bodies}\n  </worldbody>\n</mujoco>')


def drop_mjcf(h: float = PEER_STEP) -> str:
    """MJCF of the box drop (one box, centre at 0.5 m); see :func:`boxes_mjcf`."""
    return boxes_mjcf([(0.0, 0.0, DROP_CENTRE)], h)


def stack_mjcf(h: float = PEER_STEP, count: int = STACK_COUNT) -> str:
    """MJCF of jaxrb's column of ``count`` touching boxes (:func:`jaxrb.bench.contact.column_centres`)."""
    return boxes_mjcf(contact.column_centres(count), h)


def tumbler_mjcf(h: float, integrator: str = "RK4") -> str:
    """MJCF of the torque-free body: a free joint and a diagonal inertia, no gravity, no geoms.

    Args:
        h: time step (s).
        integrator: MuJoCo integrator name.

    Returns:
        The model as an XML string.
    """
    inertia = " ".join(str(v) for v in free_body.TUMBLE_INERTIA)
    return (f'<mujoco model="jaxrb_peer_tumbler">\n'
            f'  <option timestep="{h!r}" gravity="0 0 0" integrator="{integrator}"/>\n'
            f'  <worldbody><body name="tumbler"><freejoint/>'
            f'<inertial pos="0 0 0" mass="1" diaginertia="{inertia}"/></body></worldbody>\n</mujoco>')


def pyramid_centres(rows: int = PYRAMID_ROWS) -> List[Tuple[float, float]]:
    """(x, y) centres of the 2D pyramid, row by row, as in :func:`jaxrb.bench.contact.pyramid2d_scene`."""
    centres = []
    for row in range(rows):
        for column in range(rows - row):
            centres.append(((column - (rows - 1 - row) / 2.0) * 2 * HALF * 1.05, HALF + 2 * HALF * row))
    return centres


def load_peers(engines: Sequence[str]) -> Tuple[Dict[str, object], Dict[str, str]]:
    """Import the requested peers; return ``(modules, skipped)``.

    Args:
        engines: keys of :data:`ENGINES`.

    Returns:
        ``modules``: engine -> a dict of the imported modules it needs;
        ``skipped``: engine -> why it is not available.
    """
    unknown = [e for e in engines if e not in ENGINES]
    if unknown:
        raise ValueError(f"peers_engines: unknown {unknown}; valid: {', '.join(ENGINES)}")
    modules, skipped = {}, {}
    for engine in engines:
        try:
            if engine == "mujoco":
                import mujoco
                modules[engine] = {"mujoco": mujoco}
            elif engine == "mjx":
                import mujoco
                from mujoco import mjx
                modules[engine] = {"mujoco": mujoco, "mjx": mjx}
            elif engine in ("brax_spring", "brax_positional"):
                import warnings

                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    import brax
                    from brax.io import mjcf
                    if engine == "brax_spring":
                        from brax.spring import pipeline
                    else:
                        from brax.positional import pipeline
                modules[engine] = {"brax": brax, "mjcf": mjcf, "pipeline": pipeline}
            elif engine == "jax2d":
                from jax2d import engine as j2d_engine
                from jax2d import scene as j2d_scene
                from jax2d import sim_state as j2d_state
                modules[engine] = {"engine": j2d_engine, "scene": j2d_scene, "sim_state": j2d_state}
            elif engine == "pymunk":
                import pymunk
                modules[engine] = {"pymunk": pymunk}
        except Exception as error:  # an absent or broken peer is a note, not a failure
            skipped[engine] = f"not importable: {type(error).__name__}: {error}"
    return modules, skipped


def _time_jax(fn: Callable, *args, settings: dict):
    return time_jitted(fn, *args, repeats=settings["peers_repeats"], min_repeats=1,
                       budget_s=settings["peers_budget_s"])


def _scan_final(step: Callable, num_steps: int) -> Callable:
    def final(state0, *args):
        return jax.lax.scan(lambda current, _: (step(current, *args), None), state0, None,
                            length=num_steps)[0]

    return final


def _median_wall(fn: Callable, repeats: int):
    """Median wall seconds of ``fn()`` over ``repeats`` calls and the last call's result."""
    runs, out = [], None
    for _ in range(max(1, repeats)):
        start = time.perf_counter()
        out = fn()
        runs.append(time.perf_counter() - start)
    return statistics.median(runs), out


# --- jaxrb ----------------------------------------------------------------------------------

#: Appended to a jaxrb drop row's setting when it ran as a user's loop over ``vmap(step)``.
LOOP_SUFFIX = ", user loop"


def _user_loop(step: Callable, num_steps: int, batched: bool) -> Callable:
    """``(state, params) -> state``: a ``fori_loop`` over ``vmap(step)``, the loop a user writes by hand."""
    advance = jax.vmap(step, in_axes=(0, None)) if batched else step
    return lambda state, params: jax.lax.fori_loop(0, num_steps, lambda _, s: advance(s, params), state)


def _jaxrb_batched(scene_factory, dt, substeps, batch, num_steps, settings, build=None, form="rollout"):
    import jaxrb as rb

    options = {"contact": "impulse", "substeps": substeps, **(build or {})}
    model, params, state = scene_factory().build(dtype=jnp.float32, dt=dt, **options)
    step = rb.make_step(model)
    if batch > 1:
        state = contact._batched_state(state, batch)
    run = (final_state_fn if form == "rollout" else _user_loop)(step, num_steps, batch > 1)
    timing = _time_jax(run, state, params, settings=settings)
    initial = np.asarray(state.pos, dtype=np.float64).reshape((batch,) + tuple(state.pos.shape[-2:]))
    final = np.asarray(timing.output.pos, dtype=np.float64).reshape(initial.shape)
    return timing, initial, final, int(state.pos.shape[-2])


def _setting_text(dt: float, substeps: int, build=None) -> str:
    build = build or {}
    substeps = build.get("substeps", substeps)
    text = f"{build.get('contact', 'impulse')}, {fmt_step(dt)} s" + (f" × {substeps}" if substeps > 1 else "")
    if "penalty_frequency" in build:
        text += f", spring {build['penalty_frequency']:.3g} Hz"
    if "broadphase" in build:
        text += f", {build['broadphase']} broadphase ({build['broadphase_capacity']} pairs)"
    return text


def jaxrb_drop(contact_model: str, dt: float, substeps: int, batch: int, num_steps: int,
               settings: dict, form: str = "rollout") -> PeerRow:
    """jaxrb's box drop with ``contact_model`` at step ``dt`` with ``substeps``; see the module docstring.

    ``form``: ``"rollout"`` (``vmap`` of ``rb.rollout``) or ``"loop"`` (a
    ``fori_loop`` over ``vmap(step)``, as a user writes it); the same step.

    Args:
        contact_model: ``"impulse"`` or ``"penalty"`` (its default stiffness and damping).
        dt: step (s).
        substeps: substeps per step.
        batch: worlds.
        num_steps: steps per call.
        settings: section settings (``peers_repeats``, ``peers_budget_s``).

    Returns:
        A :class:`PeerRow` with ``rest_offset`` and ``rest_error`` metrics.
    """
    build = {"contact": contact_model}
    timing, _, final, bodies = _jaxrb_batched(contact.drop_scene, dt, substeps, batch, num_steps,
                                              settings, build, form)
    setting = _setting_text(dt, substeps, build) + (LOOP_SUFFIX if form == "loop" else "")
    return PeerRow("drop", "jaxrb", setting, dt, batch, bodies, num_steps,
                   timing.compile_s, timing.run_s, _rest_metrics(final[:, 0, 2]))


def _rest_metrics(heights) -> dict:
    offset = np.asarray(heights, dtype=np.float64) - HALF
    return {"rest_offset": float(np.mean(offset)), "rest_error": float(np.max(np.abs(offset)))}


def _stack_metrics(initial_top, final_top, rest_height: float) -> dict:
    """Sink and drift of the top box from (batch, dim) positions.

    Sink is the mean of ``rest_height`` (the top box's height with every box
    exactly touching, the closed form) minus its final height, so the 0–1 mm
    that :func:`world_shifts` lifts a batched world by is not counted as
    sinking; drift is the largest sideways move from each world's own start.
    It stands when every world's top box is finite, drifted less than
    :data:`STAND_DRIFT` and ended within :data:`STAND_SINK` of the rest height,
    below or above (a column thrown straight up moves no sideways).
    """
    initial_top, final_top = np.asarray(initial_top), np.asarray(final_top)
    fall = rest_height - final_top[:, -1]  # per world
    drift = float(np.max(np.linalg.norm(final_top[:, :-1] - initial_top[:, :-1], axis=-1)))
    stands = (bool(np.all(np.isfinite(final_top))) and drift < STAND_DRIFT
              and bool(np.all(np.abs(fall) < STAND_SINK)))
    return {"sink": float(np.mean(fall)), "drift": drift, "stands": stands}


def _jaxrb_standing(scene: str, make_scene, top: int, rest_height: float, contact_model: str, batch: int,
                    seconds: float, settings: dict) -> PeerRow:
    """jaxrb with ``contact_model`` (:data:`STANDING_SETTINGS`) for ``seconds``; sink and drift of body ``top``."""
    if contact_model not in STANDING_SETTINGS:
        raise ValueError(f"peers: unknown jaxrb contact model {contact_model!r} for the {scene}; valid: "
                         f"{', '.join(STANDING_SETTINGS)}")
    dt, substeps, build = STANDING_SETTINGS[contact_model][scene]
    num_steps = max(1, int(round(seconds / dt)))
    timing, initial, final, bodies = _jaxrb_batched(make_scene, dt, substeps, batch, num_steps, settings,
                                                    build)
    metrics = _stack_metrics(initial[:, top], final[:, top], rest_height)
    # A broadphase that ran out of pairs drops contacts: such a run does not count as standing.
    metrics["overflow"] = bool(np.any(np.asarray(timing.output.overflow)))
    metrics["stands"] = metrics["stands"] and not metrics["overflow"]
    return PeerRow(scene, "jaxrb", _setting_text(dt, substeps, build), dt, batch, bodies, num_steps,
                   timing.compile_s, timing.run_s, metrics)


def jaxrb_stack(contact_model: str, batch: int, seconds: float, settings: dict) -> PeerRow:
    """jaxrb's 10-box column with ``contact_model`` for ``seconds``; sink and drift of the top box."""
    return _jaxrb_standing("stack", lambda: contact.stack3d_scene(STACK_COUNT), -1, STACK_TOP_REST,
                           contact_model, batch, seconds, settings)


def jaxrb_pyramid(contact_model: str, batch: int, seconds: float, settings: dict) -> PeerRow:
    """jaxrb's 55-box 2D pyramid with ``contact_model`` for ``seconds``; does it stand."""
    return _jaxrb_standing("pyramid", lambda: contact.pyramid2d_scene(PYRAMID_ROWS), PYRAMID_TOP,
                           pyramid_centres()[PYRAMID_TOP][1], contact_model, batch, seconds, settings)


def jaxrb_flip(integrator: str, orientation: Optional[str], h: float, t_end: float, dtype,
               reference: np.ndarray, settings: dict) -> PeerRow:
    """jaxrb's torque-free flip (:func:`jaxrb.bench.free_body.run_tumble`) against ``reference``."""
    with x64(True):  # float64 runs need it; float32 runs ask for their dtype explicitly
        result = free_body.run_tumble(integrator, orientation, h, t_end, dtype, reference,
                                      repeats=settings["peers_repeats"])
    name = integrator + (f"/{orientation}" if orientation else "")
    return PeerRow("flip", "jaxrb", name, h, 1, 1, result.num_steps, result.compile_s, result.run_s,
                   {"flip_error": result.flips.max_error, "flips": result.flips.count_text,
                    "dtype": result.dtype})


# --- MuJoCo C -------------------------------------------------------------------------------

def _mujoco_one_world(mujoco, xml: str, num_steps: int, repeats: int):
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)

    def run():
        mujoco.mj_resetData(model, data)
        for _ in range(num_steps):
            mujoco.mj_step(model, data)
        return data.qpos.copy()

    run_s, qpos = _median_wall(run, repeats)
    return model, run_s, qpos


def mujoco_drop(mods: dict, num_steps: int, worlds: int, settings: dict) -> List[PeerRow]:
    """MuJoCo C box drop: one world stepped from Python, and ``worlds`` worlds in ``mujoco.rollout``."""
    mujoco = mods["mujoco"]
    xml = drop_mjcf()
    model, run_s, qpos = _mujoco_one_world(mujoco, xml, num_steps, settings["peers_repeats"])
    rows = [PeerRow("drop", "mujoco", "Euler, mj_step from Python", PEER_STEP, 1, 1, num_steps, None,
                    run_s, _rest_metrics([qpos[2]]))]
    if worlds > 1:
        try:
            from mujoco import rollout
        except ImportError as error:
            rows[0].metrics["note"] = f"mujoco.rollout missing ({error})"
            return rows
        data = mujoco.MjData(model)
        spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
        size = mujoco.mj_stateSize(model, spec)
        start = np.empty(size)
        mujoco.mj_getState(model, data, start, spec)
        initial = np.tile(start, (worlds, 1))
        initial[:, 1:1 + 7] = _free_qpos(model.qpos0, 1, world_shifts(worlds, 3))  # state = (time, qpos, ...)
        run_s, (states, _) = _median_wall(
            lambda: rollout.rollout(model, data, initial, nstep=num_steps), settings["peers_repeats"])
        rows.append(PeerRow("drop", "mujoco", "Euler, mujoco.rollout (C loop, 1 thread)", PEER_STEP,
                            worlds, 1, num_steps, None, run_s, _rest_metrics(states[:, -1, 1 + 2])))
    return rows


def mujoco_stack(mods: dict, seconds: float, settings: dict) -> PeerRow:
    """MuJoCo C 10-box column, one world, for ``seconds`` at h = 2 ms."""
    mujoco = mods["mujoco"]
    num_steps = max(1, int(round(seconds / PEER_STEP)))
    model, run_s, qpos = _mujoco_one_world(mujoco, stack_mjcf(), num_steps, settings["peers_repeats"])
    top = slice(7 * (STACK_COUNT - 1), 7 * (STACK_COUNT - 1) + 3)
    return PeerRow("stack", "mujoco", "Euler, mj_step from Python", PEER_STEP, 1, STACK_COUNT, num_steps,
                   None, run_s, _stack_metrics(model.qpos0[top][None], qpos[top][None], STACK_TOP_REST))


def _flip_error(omega_y: np.ndarray, h: float, reference: np.ndarray) -> free_body.FlipError:
    """Flip-time error of body-frame ω_y sampled at t = 0, h, 2h, ... against ``reference``."""
    omega_y = np.asarray(omega_y, dtype=np.float64)
    times = np.arange(len(omega_y)) * h
    return free_body.compare_flips(free_body.sign_changes(times, omega_y), reference)


def mujoco_flip(mods: dict, h: float, t_end: float, reference: np.ndarray, settings: dict) -> PeerRow:
    """MuJoCo C's RK4 (float64) on the torque-free body; qvel[3:6] of a free joint is body-frame ω."""
    mujoco = mods["mujoco"]
    model = mujoco.MjModel.from_xml_string(tumbler_mjcf(h))
    data = mujoco.MjData(model)
    num_steps = int(round(t_end / h))

    def run():
        mujoco.mj_resetData(model, data)
        data.qvel[3:6] = free_body.TUMBLE_ANGVEL
        omega_y = np.empty(num_steps + 1)
        omega_y[0] = data.qvel[4]
        for k in range(num_steps):
            mujoco.mj_step(model, data)
            omega_y[k + 1] = data.qvel[4]
        return omega_y

    run_s, omega_y = _median_wall(run, 1)
    flips = _flip_error(omega_y, h, reference)
    return PeerRow("flip", "mujoco", "RK4", h, 1, 1, num_steps, None, run_s,
                   {"flip_error": flips.max_error, "flips": flips.count_text, "dtype": "float64"})


# --- MJX ------------------------------------------------------------------------------------

def _mjx_batched(mods, xml, num_bodies, batch, num_steps, settings):
    mujoco, mjx = mods["mujoco"], mods["mjx"]
    with x64(False):
        model = mujoco.MjModel.from_xml_string(xml)
        mx = mjx.put_model(model)
        data0 = mjx.make_data(mx)
        qpos = jnp.asarray(_free_qpos(model.qpos0, num_bodies, world_shifts(batch, 3)), jnp.float32)
        data = jax.vmap(lambda q: data0.replace(qpos=q))(qpos)
        step = jax.vmap(mjx.step, in_axes=(None, 0))
        timing = _time_jax(lambda d, m: _scan_final(lambda c, mm: step(mm, c), num_steps)(d, m),
                           data, mx, settings=settings)
        return timing, np.asarray(qpos, np.float64), np.asarray(timing.output.qpos, np.float64)


def mjx_drop(mods: dict, batch: int, num_steps: int, settings: dict) -> PeerRow:
    """MJX box drop: ``jax.vmap`` of ``mjx.step`` over a batch of ``mjx.Data``, scanned in one jit."""
    timing, _, final = _mjx_batched(mods, drop_mjcf(), 1, batch, num_steps, settings)
    return PeerRow("drop", "mjx", "Euler, vmap(mjx.step)", PEER_STEP, batch, 1, num_steps,
                   timing.compile_s, timing.run_s, _rest_metrics(final[:, 2]))


def mjx_stack(mods: dict, batch: int, seconds: float, settings: dict) -> PeerRow:
    """MJX 10-box column at h = 2 ms, batched like :func:`mjx_drop`."""
    num_steps = max(1, int(round(seconds / PEER_STEP)))
    timing, initial, final = _mjx_batched(mods, stack_mjcf(), STACK_COUNT, batch, num_steps, settings)
    top = slice(7 * (STACK_COUNT - 1), 7 * (STACK_COUNT - 1) + 3)
    return PeerRow("stack", "mjx", "Euler, vmap(mjx.step)", PEER_STEP, batch, STACK_COUNT, num_steps,
                   timing.compile_s, timing.run_s, _stack_metrics(initial[:, top], final[:, top], STACK_TOP_REST))


def mjx_flip(mods: dict, h: float, t_end: float, reference: np.ndarray, settings: dict) -> PeerRow:
    """MJX's RK4 in float32 on the torque-free body, every step's body-frame ω_y kept."""
    mujoco, mjx = mods["mujoco"], mods["mjx"]
    num_steps = int(round(t_end / h))
    with x64(False):
        model = mujoco.MjModel.from_xml_string(tumbler_mjcf(h))
        mx = mjx.put_model(model)
        data = mjx.make_data(mx)
        data = data.replace(qvel=data.qvel.at[3:6].set(jnp.asarray(free_body.TUMBLE_ANGVEL, jnp.float32)))

        def trajectory(d, m):
            def body(current, _):
                following = mjx.step(m, current)
                return following, following.qvel[4]

            return jax.lax.scan(body, d, None, length=num_steps)[1]

        timing = _time_jax(trajectory, data, mx, settings=settings)
        omega_y = np.concatenate([[free_body.TUMBLE_ANGVEL[1]], np.asarray(timing.output, np.float64)])
        dtype = str(data.qvel.dtype)
    flips = _flip_error(omega_y, h, reference)
    return PeerRow("flip", "mjx", "RK4", h, 1, 1, num_steps, timing.compile_s, timing.run_s,
                   {"flip_error": flips.max_error, "flips": flips.count_text, "dtype": dtype})


# --- Brax -----------------------------------------------------------------------------------

def _brax_batched(mods, xml, num_bodies, batch, num_steps, settings):
    import warnings

    mjcf, pipeline = mods["mjcf"], mods["pipeline"]
    with x64(False), warnings.catch_warnings():
        warnings.simplefilter("ignore")  # Brax warns that it is unmaintained on every load
        system = mjcf.loads(xml)
        qpos = jnp.asarray(_free_qpos(np.asarray(system.init_q), num_bodies, world_shifts(batch, 3)),
                           jnp.float32)
        zero_qd = jnp.zeros(system.qd_size(), jnp.float32)
        states = jax.jit(jax.vmap(lambda q: pipeline.init(system, q, zero_qd)))(qpos)
        act = jnp.zeros(system.act_size(), jnp.float32)
        step = jax.vmap(lambda s, sys_: pipeline.step(sys_, s, act), in_axes=(0, None))
        timing = _time_jax(_scan_final(step, num_steps), states, system, settings=settings)
        return timing, np.asarray(qpos, np.float64), np.asarray(timing.output.q, np.float64)


def brax_drop(engine: str, mods: dict, batch: int, num_steps: int, settings: dict) -> PeerRow:
    """Brax box drop with the spring or positional pipeline, system from :func:`drop_mjcf`."""
    timing, _, final = _brax_batched(mods, drop_mjcf(), 1, batch, num_steps, settings)
    return PeerRow("drop", engine, "vmap(pipeline.step), system from MJCF", PEER_STEP, batch, 1,
                   num_steps, timing.compile_s, timing.run_s, _rest_metrics(final[:, 2]))


def brax_stack(engine: str, mods: dict, batch: int, seconds: float, settings: dict) -> PeerRow:
    """Brax 10-box column at h = 2 ms, batched like :func:`brax_drop`."""
    num_steps = max(1, int(round(seconds / PEER_STEP)))
    timing, initial, final = _brax_batched(mods, stack_mjcf(), STACK_COUNT, batch, num_steps, settings)
    top = slice(7 * (STACK_COUNT - 1), 7 * (STACK_COUNT - 1) + 3)
    return PeerRow("stack", engine, "vmap(pipeline.step), system from MJCF", PEER_STEP, batch,
                   STACK_COUNT, num_steps, timing.compile_s, timing.run_s,
                   _stack_metrics(initial[:, top], final[:, top], STACK_TOP_REST))


# --- Jax2D and pymunk (2D) -------------------------------------------------------------------

def jax2d_pyramid(mods: dict, batch: int, seconds: float, settings: dict) -> PeerRow:
    """Jax2D's 55-box pyramid at its default step (1/60 s, 10 solver iterations), vmapped."""
    j2d_engine, j2d_scene, j2d_state = mods["engine"], mods["scene"], mods["sim_state"]
    count = len(pyramid_centres())
    fixed = 4  # Jax2D keeps its floor and walls in the first polygon slots
    import warnings

    with x64(False), warnings.catch_warnings():
        # Jax2D asks for float64 in places; with x64 off that is float32, as intended here.
        warnings.filterwarnings("ignore", message="Explicitly requested dtype float64")
        # Two (inactive) circles: Jax2D indexes its circle-circle pair table, which one circle leaves empty.
        static = j2d_state.StaticSimParams(num_polygons=fixed + count, num_circles=2, num_joints=1,
                                           num_thrusters=1)
        params = j2d_state.SimParams()
        # Jax2D's usual scene: floor, side walls and ceiling fill the fixed slots (the walls
        # stand 2.5 m from the pyramid's centre); new boxes go into the first free slot.
        state = j2d_engine.create_empty_sim(static, add_floor=True, add_walls_and_ceiling=True,
                                            scene_size=5.0)
        floor_top = float(jnp.max(state.polygon.position[0, 1] + state.polygon.vertices[0, :, 1]))
        state = state.replace(polygon=state.polygon.replace(
            friction=state.polygon.friction.at[0].set(FRICTION)))
        density = 1.0 / (2 * HALF) ** 2  # 1 kg boxes
        for x, y in pyramid_centres():
            state, _ = j2d_scene.add_rectangle_to_scene(
                state, static, jnp.array([2.5 + x, floor_top + y]), jnp.array([2 * HALF, 2 * HALF]),
                density=density, friction=FRICTION)
        shifts = jnp.asarray(world_shifts(batch, 2), jnp.float32)
        moving = jnp.arange(static.num_polygons) >= fixed
        batched = jax.vmap(lambda s: state.replace(polygon=state.polygon.replace(
            position=state.polygon.position + jnp.where(moving[:, None], s, 0.0))))(shifts)
        physics = j2d_engine.PhysicsEngine(static)
        actions = jnp.zeros(static.num_joints + static.num_thrusters, jnp.float32)
        num_steps = max(1, int(round(seconds / float(params.dt))))
        step = jax.vmap(lambda s, p: physics.step(s, p, actions)[0], in_axes=(0, None))
        timing = _time_jax(_scan_final(step, num_steps), batched, params, settings=settings)
        top = fixed + PYRAMID_TOP
        initial = np.asarray(batched.polygon.position[:, top], np.float64)
        final = np.asarray(timing.output.polygon.position[:, top], np.float64)
    return PeerRow("pyramid", "jax2d", "1/60 s, 10 iterations, vmap(engine.step)", float(params.dt),
                   batch, count, num_steps, timing.compile_s, timing.run_s,
                   _stack_metrics(initial, final, pyramid_centres()[PYRAMID_TOP][1]))


def pymunk_pyramid(mods: dict, seconds: float, settings: dict) -> PeerRow:
    """pymunk (Chipmunk, C) 55-box pyramid in one world at 1/60 s, 10 iterations."""
    pymunk = mods["pymunk"]
    h = 1 / 60
    num_steps = max(1, int(round(seconds / h)))

    def run():
        space = pymunk.Space()
        space.gravity = (0.0, -9.81)
        space.iterations = 10
        space.collision_slop = 1e-3  # its default, 0.1, is meant for pixels, not metres
        floor = pymunk.Segment(space.static_body, (-10.0, 0.0), (10.0, 0.0), 0.0)
        floor.friction = FRICTION
        space.add(floor)
        bodies = []
        for x, y in pyramid_centres():
            body = pymunk.Body(1.0, pymunk.moment_for_box(1.0, (2 * HALF, 2 * HALF)))
            body.position = (x, y)
            shape = pymunk.Poly.create_box(body, (2 * HALF, 2 * HALF))
            shape.friction = FRICTION
            space.add(body, shape)
            bodies.append(body)
        start = time.perf_counter()
        for _ in range(num_steps):
            space.step(h)
        return time.perf_counter() - start, tuple(bodies[PYRAMID_TOP].position)

    runs = [run() for _ in range(max(1, settings["peers_repeats"]))]
    run_s = statistics.median(r[0] for r in runs)
    initial = np.array([pyramid_centres()[PYRAMID_TOP]])
    return PeerRow("pyramid", "pymunk", "1/60 s, 10 iterations, space.step", h, 1,
                   len(pyramid_centres()), num_steps, None, run_s,
                   _stack_metrics(initial, np.array([runs[-1][1]]), initial[0, 1]))


# --- targets --------------------------------------------------------------------------------

def _find(rows: Sequence[PeerRow], scene: str, engine: str, setting: Optional[str] = None,
          batch: Optional[int] = None) -> Optional[PeerRow]:
    for row in rows:
        if row.scene == scene and row.engine == engine and \
                (setting is None or row.setting == setting) and (batch is None or row.batch == batch):
            return row
    return None


def _speed_target(scene, text, mine, peer, factor, simulated: bool = False) -> Target:
    """``mine`` at least ``factor`` × ``peer``: in body-steps/s, or with ``simulated`` in body-seconds/s.

    Rows of different steps compare only in simulated time (body-s/s = body-steps/s · h).
    """
    if mine is None or peer is None:
        return Target(scene, text, "peer or jaxrb row missing", None)
    rate = (lambda row: row.body_steps_per_s * row.h) if simulated else (lambda row: row.body_steps_per_s)
    value = ratio(rate(mine), rate(peer))
    return Target(scene, text, f"{fmt_fixed(value, 2)}× ({fmt_si(rate(mine))} vs "
                               f"{fmt_si(rate(peer))} {'body-s/s' if simulated else 'body-steps/s'})",
                  bool(value >= factor) if math.isfinite(value) else None)


def _best_flip(rows, h, dtype) -> Optional[PeerRow]:
    candidates = [r for r in rows if r.scene == "flip" and r.engine == "jaxrb" and r.metrics.get("dtype") == dtype
                  and abs(r.h - h) < 1e-12]
    return min(candidates, key=lambda r: r.metrics["flip_error"]) if candidates else None


def evaluate_targets(rows: Sequence[PeerRow]) -> List[Target]:
    """The targets (issues 6 and 60) that this section measures, checked against ``rows``.

    The box-drop, stack and pyramid targets are checked for every jaxrb row of
    the scene (each setting); speed ratios compare rows at the same batch, the
    drop's in body-steps/s (one h), the stack's and pyramid's in simulated
    body-seconds/s (the engines step at different h). A target whose rows
    are missing (peer absent) is NOT MEASURED.

    Args:
        rows: the :class:`PeerRow` results of :func:`run_peers` (or made up, in tests).

    Returns:
        One :class:`Target` per checked clause.
    """
    targets = []
    for mine in [r for r in rows if r.scene == "drop" and r.engine == "jaxrb"]:
        tag = f"box drop, jaxrb {mine.setting}:"
        spring = _find(rows, "drop", "brax_spring", batch=mine.batch)
        mjx_row = _find(rows, "drop", "mjx", batch=mine.batch)
        targets.append(_speed_target("drop", f"{tag} ≥ 5× Brax spring body-steps/s", mine, spring, 5.0))
        targets.append(_speed_target("drop", f"{tag} ≥ 30× MJX body-steps/s", mine, mjx_row, 30.0))
        error = mine.metrics.get("rest_error")
        targets.append(Target("drop", f"{tag} rests within 0.5 mm of 0.1 m",
                              f"{fmt_fixed(1e3 * error, 3)} mm" if error is not None else "—",
                              None if error is None else bool(error <= 5e-4)))
        if spring is None or spring.compile_s is None:
            targets.append(Target("drop", f"{tag} compile ≤ ½ Brax spring's", "Brax spring missing", None))
        else:
            targets.append(Target("drop", f"{tag} compile ≤ ½ Brax spring's",
                                  f"{mine.compile_s:.2f} s vs {spring.compile_s:.2f} s",
                                  bool(mine.compile_s <= 0.5 * spring.compile_s)))
    for loop in [r for r in rows if r.scene == "drop" and r.engine == "jaxrb" and r.setting.endswith(LOOP_SUFFIX)]:
        scanned = _find(rows, "drop", "jaxrb", setting=loop.setting[:-len(LOOP_SUFFIX)], batch=loop.batch)
        text = f"box drop, jaxrb {loop.setting[:-len(LOOP_SUFFIX)]}: user loop within 10 % of rollout"
        value = ratio(loop.body_steps_per_s, scanned.body_steps_per_s if scanned else None)
        targets.append(Target("drop", text, f"{fmt_fixed(value, 2)}×",
                              bool(abs(value - 1.0) <= 0.1) if math.isfinite(value) else None))
    for mine in [r for r in rows if r.scene == "stack" and r.engine == "jaxrb"]:
        tag = f"10-box stack, jaxrb {mine.setting}:"
        sink, drift = mine.metrics["sink"], mine.metrics["drift"]
        seconds = mine.num_steps * mine.h
        targets.append(Target("stack", f"{tag} sinks < 2 mm over {seconds:g} s",
                              f"{1e3 * sink:.3f} mm", bool(abs(sink) < 2e-3)))
        targets.append(Target("stack", f"{tag} drifts < 1 mm over {seconds:g} s",
                              f"{1e3 * drift:.3f} mm", bool(drift < 1e-3)))
        targets.append(_speed_target("stack", f"{tag} ≥ 5× Brax spring body-s/s", mine,
                                     _find(rows, "stack", "brax_spring", batch=mine.batch), 5.0, simulated=True))
    jax2d_row = _find(rows, "pyramid", "jax2d")
    small_batch = jax2d_row.batch if jax2d_row else None
    for small in [r for r in rows if r.scene == "pyramid" and r.engine == "jaxrb"
                  and (small_batch is None or r.batch == small_batch) and r.batch != PYMUNK_TARGET_BATCH]:
        tag = f"pyramid, jaxrb {small.setting}:"
        targets.append(_speed_target("pyramid", f"{tag} ≥ 20× Jax2D body-s/s at the same batch",
                                     small, jax2d_row, 20.0, simulated=True))
        big = _find(rows, "pyramid", "jaxrb", setting=small.setting, batch=PYMUNK_TARGET_BATCH)
        targets.append(_speed_target("pyramid", f"{tag} at batch {PYMUNK_TARGET_BATCH} > pymunk in one world "
                                                 "(body-s/s)", big, _find(rows, "pyramid", "pymunk"), 1.0,
                                     simulated=True))
        targets.append(Target("pyramid", f"{tag} still standing after {small.num_steps * small.h:g} s",
                              f"top box drift {1e3 * small.metrics['drift']:.2f} mm, sink "
                              f"{1e3 * small.metrics['sink']:.2f} mm", bool(small.metrics["stands"])))
    steps = sorted({r.h for r in rows if r.scene == "flip"}, reverse=True)
    if steps:
        best32 = [_best_flip(rows, h, "float32") for h in steps]
        if all(b is not None for b in best32):
            targets.append(Target(
                "flip", "flip in float32: error < 0.005 s at every h (best integrator)",
                "; ".join(f"{fmt_step(h)}: {fmt_sci(b.metrics['flip_error'])} s ({b.setting})"
                          for h, b in zip(steps, best32)),
                all(b.metrics["flip_error"] < 5e-3 for b in best32)))
        parts, oks = [], []
        for h in steps:
            best64, reference = _best_flip(rows, h, "float64"), _find_flip(rows, "mujoco", h)
            if best64 is None or reference is None:
                continue
            mine_error, peer_error = best64.metrics["flip_error"], reference.metrics["flip_error"]
            oks.append(bool(mine_error <= 2.0 * peer_error))
            parts.append(f"{fmt_step(h)}: {fmt_sci(mine_error)} vs {fmt_sci(peer_error)} s")
        targets.append(Target("flip", "flip in float64: within 2× of MuJoCo C's RK4 at the same h",
                              "; ".join(parts) if parts else "MuJoCo C or jaxrb float64 missing",
                              all(oks) if oks else None))
    return targets


def _find_flip(rows, engine, h) -> Optional[PeerRow]:
    for row in rows:
        if row.scene == "flip" and row.engine == engine and abs(row.h - h) < 1e-12:
            return row
    return None


# --- the section ----------------------------------------------------------------------------

def peer_process_flags(flags: Optional[str] = None) -> Optional[str]:
    """``XLA_FLAGS`` for a child process that runs the peers, or ``None`` to run them in this one.

    Args:
        flags: this process's ``XLA_FLAGS`` (default: the environment's).

    Returns:
        ``flags`` without jaxrb's LLVM unroll limit where they hold it, else ``None``.
    """
    flags = os.environ.get("XLA_FLAGS", "") if flags is None else flags
    limit = rb_compile.UNROLL_LIMIT_OPTION
    if limit not in flags:
        return None
    return flags.replace("," + limit, "").replace(limit + ",", "").replace(limit, "")


def _run_in_child(settings: dict, flags: str) -> Tuple[List[PeerRow], Dict[str, str]]:
    """:func:`run_peers` with ``settings`` in a new interpreter whose ``XLA_FLAGS`` are ``flags``.

    The child's progress lines go to this process's stderr; a child that
    fails becomes one note in ``skipped``.
    """
    with tempfile.TemporaryDirectory() as folder:
        path = os.path.join(folder, "peers.pickle")
        with open(path, "wb") as handle:
            pickle.dump(settings, handle)
        code = ("import pickle, sys\n"
                "from benchmarks import peers\n"
                "settings = pickle.load(open(sys.argv[1], 'rb'))\n"
                "log = lambda text: print(text, file=sys.stderr, flush=True)\n"
                "result = peers.run_peers(settings, log)\n"
                "pickle.dump(result, open(sys.argv[1], 'wb'))\n")
        # The checkout's root on the path, so that the child imports this folder from any working directory.
        root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
        path_list = os.pathsep.join([root] + ([os.environ["PYTHONPATH"]] if os.environ.get("PYTHONPATH") else []))
        done = subprocess.run([sys.executable, "-c", code, path],
                              env=dict(os.environ, XLA_FLAGS=flags, PYTHONPATH=path_list),
                              stdout=subprocess.DEVNULL, stderr=None)
        if done.returncode != 0:
            scenes = ", ".join(settings["peers_scenes"])
            return [], {f"peers ({scenes})": f"failed: their process exited with {done.returncode}"}
        with open(path, "rb") as handle:
            return pickle.load(handle)


def run_peers(settings: dict, log=None) -> Tuple[List[PeerRow], Dict[str, str]]:
    """Run every scene for jaxrb and every available peer.

    Where :func:`peer_process_flags` asks for it, each scene's peers run in a
    child process after jaxrb's rows of the scene.

    Args:
        settings: :data:`QUICK`, :data:`FULL` or a dict with the same keys.
        log: optional ``log(text)`` for progress lines.

    Returns:
        ``(rows, skipped)``: the :class:`PeerRow` results and, per skipped
        peer (or peer and scene), the reason.
    """
    settings = {**FULL, **settings}
    log = log or (lambda text: None)
    unknown = [s for s in settings["peers_scenes"] if s not in SCENE_TITLES]
    if unknown:
        raise ValueError(f"peers_scenes: unknown {unknown}; valid: {', '.join(SCENE_TITLES)}")
    modules, skipped = load_peers(settings["peers_engines"])
    child_flags = peer_process_flags()
    if modules and child_flags is not None:
        rows: List[PeerRow] = []
        for scene in settings["peers_scenes"]:
            here = dict(settings, peers_scenes=(scene,))
            mine, why_mine = _run_here(dict(here, peers_engines=()), {}, {}, log)
            theirs, why_theirs = _run_in_child(dict(here, peers_with_jaxrb=False), child_flags)
            rows += mine + theirs
            skipped.update({**why_mine, **why_theirs})
        return rows, skipped
    return _run_here(settings, modules, skipped, log)


def _run_here(settings: dict, modules: dict, skipped: Dict[str, str],
              log) -> Tuple[List[PeerRow], Dict[str, str]]:
    """:func:`run_peers` in this process, with the peers ``modules`` that :func:`load_peers` found."""
    rows: List[PeerRow] = []

    def attempt(engine: str, scene: str, make: Callable):
        """Run one peer measurement; a failure becomes a note instead of ending the report."""
        if (engine != "jaxrb" and engine not in modules) or \
                (engine == "jaxrb" and not settings["peers_with_jaxrb"]):
            return
        try:
            made = make()
        except Exception as error:
            skipped[f"{engine} ({scene})"] = f"failed: {type(error).__name__}: {str(error)[:300]}"
            log(f"peers {scene:>7} {engine}: FAILED {type(error).__name__}: {error}")
            return
        for row in made if isinstance(made, list) else [made]:
            rows.append(row)
            log(f"peers {scene:>7} {ENGINE_NAMES[row.engine]:>15} batch {row.batch:>5}: compile "
                f"{fmt_fixed(row.compile_s, 2)} s, run {row.run_s:.3f} s, "
                f"{fmt_si(row.body_steps_per_s, ' body-steps/s')} {row.metrics}")

    scenes = settings["peers_scenes"]
    if "drop" in scenes:
        batch, steps = settings["peers_drop_batch"], settings["peers_drop_steps"]
        for model, dt, substeps in settings["peers_drop_jaxrb"]:
            for form in ("rollout", "loop"):
                attempt("jaxrb", "drop", lambda m=model, d=dt, n=substeps, f=form: jaxrb_drop(
                    m, d, n, batch, steps, settings, f))
        attempt("mujoco", "drop", lambda: mujoco_drop(modules["mujoco"], steps,
                                                      settings["peers_mujoco_worlds"], settings))
        attempt("mjx", "drop", lambda: mjx_drop(modules["mjx"], batch, steps, settings))
        for engine in ("brax_spring", "brax_positional"):
            attempt(engine, "drop", lambda e=engine: brax_drop(e, modules[e], batch, steps, settings))
    if "stack" in scenes:
        batch, seconds = settings["peers_stack_batch"], settings["peers_stack_seconds"]
        for model in settings["peers_stack_jaxrb"]:
            attempt("jaxrb", "stack", lambda m=model: jaxrb_stack(m, batch, seconds, settings))
        attempt("mujoco", "stack", lambda: mujoco_stack(modules["mujoco"], seconds, settings))
        attempt("brax_spring", "stack", lambda: brax_stack("brax_spring", modules["brax_spring"], batch,
                                                           seconds, settings))
        if settings["peers_stack_mjx"]:
            attempt("mjx", "stack", lambda: mjx_stack(modules["mjx"], batch, seconds, settings))
    if "pyramid" in scenes:
        batch, seconds = settings["peers_pyramid_batch"], settings["peers_pyramid_seconds"]
        big_batch, big_seconds = settings["peers_pyramid_big_batch"], settings["peers_pyramid_big_seconds"]
        for model in settings["peers_pyramid_jaxrb"]:
            attempt("jaxrb", "pyramid", lambda m=model: jaxrb_pyramid(m, batch, seconds, settings))
            if big_batch:
                attempt("jaxrb", "pyramid", lambda m=model: jaxrb_pyramid(m, big_batch, big_seconds, settings))
        attempt("jax2d", "pyramid", lambda: jax2d_pyramid(modules["jax2d"], batch, seconds, settings))
        attempt("pymunk", "pyramid", lambda: pymunk_pyramid(modules["pymunk"], seconds, settings))
    if "flip" in scenes:
        horizon = settings["peers_flip_horizon"]
        reference = analytic.flip_times(free_body.TUMBLE_INERTIA, free_body.TUMBLE_ANGVEL, horizon)
        for h in settings["peers_flip_steps"]:
            for integrator, orientation in settings["peers_flip_configs"]:
                for dtype in (jnp.float32, jnp.float64):
                    attempt("jaxrb", "flip", lambda i=integrator, o=orientation, d=dtype, hh=h: jaxrb_flip(
                        i, o, hh, horizon, d, reference, settings))
            attempt("mujoco", "flip", lambda hh=h: mujoco_flip(modules["mujoco"], hh, horizon, reference,
                                                               settings))
            if settings["peers_flip_mjx"]:
                attempt("mjx", "flip", lambda hh=h: mjx_flip(modules["mjx"], hh, horizon, reference, settings))
    if "gradient" in scenes:
        from benchmarks import peer_gradients  # it builds on this module

        steps = settings["peers_gradient_steps"]
        for model, method in peer_gradients.JAXRB_SETTINGS:
            attempt("jaxrb", "gradient", lambda m=model, r=method: peer_gradients.jaxrb_gradient(m, r, steps,
                                                                                                 settings))
        attempt("mjx", "gradient", lambda: peer_gradients.mjx_gradient(modules["mjx"], steps, settings))
        for engine in ("brax_spring", "brax_positional"):
            attempt(engine, "gradient", lambda e=engine: peer_gradients.brax_gradient(e, modules[e], steps,
                                                                                      settings))
        batch = settings["peers_gradient_batch"]
        if batch:  # MJX's and Brax positional's gradients are NaN in one world, and 5-20x slower
            attempt("jaxrb", "gradient", lambda: peer_gradients.jaxrb_gradient("penalty", "adjoint", steps,
                                                                               settings, batch))
            attempt("brax_spring", "gradient", lambda: peer_gradients.brax_gradient(
                "brax_spring", modules["brax_spring"], steps, settings, batch))
    return rows, skipped


def _metric_cells(scene: str, row: PeerRow) -> list:
    m = row.metrics
    if scene == "drop":
        return [fmt_fixed(1e3 * m["rest_offset"], 3), fmt_fixed(1e3 * m["rest_error"], 3)]
    stands = "yes" if m["stands"] else ("NO (broadphase overflow)" if m.get("overflow") else "NO")
    return [fmt_fixed(1e3 * m["sink"], 3), fmt_fixed(1e3 * m["drift"], 3), stands]


def scene_table(scene: str, rows: Sequence[PeerRow]) -> str:
    """Markdown table of one contact scene: every engine's row and jaxrb / peer speed ratios.

    Args:
        scene: ``"drop"``, ``"stack"`` or ``"pyramid"``.
        rows: all rows (other scenes are ignored).

    Returns:
        The table; one ratio column per jaxrb row of the scene (jaxrb body-steps/s
        over the row's).
    """
    mine = [r for r in rows if r.scene == scene and r.engine == "jaxrb"]
    ordered = mine + [r for r in rows if r.scene == scene and r.engine != "jaxrb"]
    extra = (["rest z − 0.1 (mm)", "max |z − 0.1| (mm)"] if scene == "drop"
             else ["sink (mm)", "drift (mm)", "stands"])
    headers = (["engine", "setting", "h (s)", "batch", "bodies", "steps", "compile (s)", "run (s)",
                "body-steps/s", "body-s/s"] + [f"jaxrb {r.setting} b{r.batch} / this" for r in mine] + extra)
    table_rows = []
    for row in ordered:
        table_rows.append(
            [ENGINE_NAMES[row.engine], row.setting, fmt_step(row.h), row.batch, row.num_bodies, row.num_steps,
             fmt_fixed(row.compile_s, 2), fmt_fixed(row.run_s, 3), fmt_si(row.body_steps_per_s),
             fmt_si(row.body_steps_per_s * row.h)]
            + [fmt_fixed(ratio(r.body_steps_per_s, row.body_steps_per_s), 2) + "×" for r in mine]
            + _metric_cells(scene, row))
    return markdown_table(headers, table_rows, align=["l", "l"] + ["r"] * (len(headers) - 2))


def flip_table(rows: Sequence[PeerRow]) -> str:
    """Markdown table of flip-time errors: one row per engine, setting and dtype, one column per h.

    Args:
        rows: all rows (non-flip rows are ignored).

    Returns:
        The table.
    """
    flips = [r for r in rows if r.scene == "flip"]
    steps = sorted({r.h for r in flips}, reverse=True)
    keys = []
    for row in flips:
        key = (row.engine, row.setting, row.metrics.get("dtype"))
        if key not in keys:
            keys.append(key)
    headers = ["engine", "setting", "dtype"] + [f"error at h = {fmt_step(h)} (s)" for h in steps] + \
              ["compile (s), first h"]
    table_rows = []
    for engine, setting, dtype in keys:
        cells, compile_s = [], None
        for h in steps:
            match = [r for r in flips if (r.engine, r.setting, r.metrics.get("dtype")) == (engine, setting, dtype)
                     and abs(r.h - h) < 1e-12]
            if match:
                error = match[0].metrics["flip_error"]
                text = fmt_sci(error)
                if not math.isfinite(error):
                    text += f" ({match[0].metrics['flips']} flips)"
                cells.append(text)
                compile_s = compile_s if compile_s is not None else match[0].compile_s
            else:
                cells.append("—")
        table_rows.append([ENGINE_NAMES[engine], setting, dtype] + cells + [fmt_fixed(compile_s, 2)])
    return markdown_table(headers, table_rows)


def targets_table(targets: Sequence[Target]) -> str:
    """Markdown table of targets with their measured values and PASS / MISSED / NOT MEASURED."""
    return markdown_table(["target", "measured", "status"],
                          [[t.text, t.measured, f"**{t.status}**"] for t in targets],
                          align=["l", "l", "l"])


def markdown(rows: Sequence[PeerRow], skipped: Dict[str, str], settings: dict) -> str:
    """The section's Markdown from its results.

    Args:
        rows: :class:`PeerRow` results.
        skipped: peer (or "peer (scene)") -> reason it is missing.
        settings: the settings the rows were measured with.

    Returns:
        Markdown text: a paragraph of method, one table per scene, the flip
        table, the targets table and the skipped peers.
    """
    settings = {**FULL, **settings}
    parts = [
        "Peers and jaxrb run one after the other on the same scenes"
        + (", each scene's peers in a process of their own without jaxrb's LLVM unroll limit "
           "(jaxrb.compile.UNROLL_LIMIT_OPTION; the XLA flags otherwise the same). "
           if peer_process_flags() is not None and any(r.engine != "jaxrb" for r in rows)
           else ", in the same process. ") +
        "float32 for every JAX engine (peers' JAX code runs with x64 off); MuJoCo C is float64. "
        "*compile* = trace + lower + compile (— for compiled C code); *run* = median wall time of one "
        "call (after a warm-up call for jitted code), with block_until_ready; body-steps/s = batch · "
        "bodies · steps / run (a jaxrb step includes its substeps); body-s/s = body-steps/s · h, the "
        "simulated body-seconds per wall second, which is fair across step sizes. Batched worlds "
        "differ by a tiny per-world shift of every body (±1 mm along the ground, 0–1 mm up). "
        "Ratios are jaxrb body-steps/s over the row's; the targets compare rows at the same batch.",
    ]
    titles = {
        "drop": (f"0.2 m box, 1 kg, released at z = {DROP_CENTRE} m, μ = {FRICTION}; peers at h = 2 ms, "
                 f"jaxrb at the settings its rows name; {settings['peers_drop_steps']} steps; rest "
                 "error after the rollout."),
        "stack": (f"{STACK_COUNT} boxes (0.2 m, 1 kg) in a column, {settings['peers_stack_seconds']:g} s; "
                  "sink = how far the top box ends below its height with every box touching (mean over "
                  "worlds), drift = its sideways move (largest over worlds)."),
        "pyramid": (f"55 boxes (0.2 m, 1 kg) in 10 rows with 5 % gaps, μ = {FRICTION}, "
                    f"{settings['peers_pyramid_seconds']:g} s; stands = top box moved < "
                    f"{STAND_DRIFT * 100:g} cm sideways and sank < {STAND_SINK * 100:g} cm."),
    }
    for scene in ("drop", "stack", "pyramid"):
        if any(r.scene == scene for r in rows):
            parts += [f"**{SCENE_TITLES[scene]}**: {titles[scene]}", "", scene_table(scene, rows)]
    if any(r.scene == "flip" for r in rows):
        parts += [f"**{SCENE_TITLES['flip']}**: inertia {free_body.TUMBLE_INERTIA} kg m², ω0 = "
                  f"{free_body.TUMBLE_ANGVEL} rad/s, {settings['peers_flip_horizon']:g} s; largest error of "
                  "the flip times (sign changes of body-frame ω_y, linear interpolation between steps) "
                  "against `jaxrb.analytic.flip_times`; inf = flips missing.", "", flip_table(rows)]
    if any(r.scene == "gradient" for r in rows):
        from benchmarks import peer_gradients

        parts += [f"**{SCENE_TITLES['gradient']}**: the box drop at h = 2 ms for "
                  f"{settings['peers_gradient_steps']} steps, float32, in one world and in a batch of worlds "
                  "(the loss their mean); the gradient of the mean over the steps "
                  "of the squares of position, velocity, angular velocity and the quaternion's vector part, "
                  "the same loss in every engine, so a loss far from the others' is a different motion. MJX "
                  "runs one solver iteration: its solver's `while_loop` cannot be reversed (MuJoCo issue #2259). "
                  "Speed columns: jaxrb's gradient body-steps/s over the row's at the same batch.", "",
                  peer_gradients.gradient_table(rows)]
    targets = evaluate_targets(rows)
    if targets:
        parts += ["**Issue-6 targets** measured here (the gradient target is in the gradient "
                  "section):", "", targets_table(targets)]
    if skipped:
        parts += ["**Skipped**: " + "; ".join(f"{ENGINE_NAMES.get(k, k)}: {v}" for k, v in skipped.items())
                  + ". Install the peers with `pip install -e \".[peers]\"`."]
    left_out = [SCENE_TITLES[scene] for scene in SCENE_TITLES if scene not in settings["peers_scenes"]]
    left_out += [ENGINE_NAMES[engine] for engine in ENGINES if engine not in settings["peers_engines"]]
    if not settings["peers_flip_mjx"] and "mjx" in settings["peers_engines"]:
        left_out.append("MJX's flip")
    if left_out:
        parts.append(f"**Not run with these settings**: {', '.join(left_out)} (the full run has them).")
    return "\n\n".join(p for p in parts if p != "").replace("\n\n\n", "\n\n")


def peers_section(settings: Optional[dict] = None, log=None):
    """Run the peers benchmark; return ``(markdown, results)`` like the other sections.

    Args:
        settings: :data:`QUICK`, :data:`FULL` or any subset of their keys (the
            rest from :data:`FULL`); other keys are ignored.
        log: optional ``log(text)`` for progress lines.

    Returns:
        ``(markdown, results)`` with ``results`` a dict: ``rows`` (list of
        :class:`PeerRow`), ``skipped`` (dict of reasons) and ``targets`` (list of
        :class:`Target`).
    """
    settings = {**FULL, **{k: v for k, v in (settings or {}).items() if k.startswith("peers_")}}
    rows, skipped = run_peers(settings, log)
    text = markdown(rows, skipped, settings)
    return text, {"rows": rows, "skipped": skipped, "targets": evaluate_targets(rows)}
