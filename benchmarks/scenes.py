"""The peers' scenes and what every engine's run returns (:mod:`benchmarks.peers` runs them).

The scenes are jaxrb's own benchmark scenes (:mod:`jaxrb.bench.contact`,
:mod:`jaxrb.bench.free_body`): the constants that size them, jaxrb's settings
for them (:data:`DROP_JAXRB`, :data:`STANDING_SETTINGS`), the same bodies as
MJCF for MuJoCo, MJX and Brax (:func:`boxes_mjcf`, :func:`tumbler_mjcf`) and
the 2D pyramid's centres for Jax2D and pymunk (:func:`pyramid_centres`).
Every engine's run (:mod:`benchmarks.jaxrb_runs`, :mod:`benchmarks.peer_runs`,
:mod:`benchmarks.peer_gradients`) gives a :class:`PeerRow`, its figures from
the same functions (:func:`rest_metrics`, :func:`stack_metrics`) and its
jitted code timed by :func:`time_jax`.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
from typing import Callable, List, Optional, Sequence, Tuple

import jax
import numpy as np

from jaxrb.bench import contact, free_body
from jaxrb.bench.timing import time_jitted

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

#: Every peer the section knows, in report order.
ENGINES = ("mujoco", "mjx", "brax_spring", "brax_positional", "jax2d", "pymunk")
ENGINE_NAMES = {"jaxrb": "jaxrb", "mujoco": "MuJoCo C", "mjx": "MJX", "brax_spring": "Brax spring",
                "brax_positional": "Brax positional", "jax2d": "Jax2D", "pymunk": "pymunk"}
SCENE_TITLES = {"drop": "Box drop", "stack": "10-box stack", "pyramid": "2D 10-row pyramid (55 boxes)",
                "flip": "Torque-free flip", "gradient": "Gradient through contact"}

#: Appended to a jaxrb drop row's setting when it ran as a user's loop over ``vmap(step)``.
LOOP_SUFFIX = ", user loop"
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
#: (docs/design.md, 'Current figures').
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


# --- scenes ---------------------------------------------------------------------------------

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


def free_qpos(qpos0: np.ndarray, num_bodies: int, shifts: np.ndarray) -> np.ndarray:
    """Free-joint positions of a batch of worlds, each world's shift added to every body.

    Args:
        qpos0: (7·n,) the model's free-joint positions (position, then (w, x, y, z) quaternion, per body).
        num_bodies: n.
        shifts: (batch, 3) per-world offsets (:func:`world_shifts`).

    Returns:
        (batch, 7·n) positions.
    """
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


# --- figures and timing ---------------------------------------------------------------------

def rest_metrics(heights) -> dict:
    """Resting figures of a box drop from the box's final centre heights.

    Args:
        heights: (batch,) final heights of the box's centre (m), one per world.

    Returns:
        ``{"rest_offset": mean of height − 0.1 m, "rest_error": its largest magnitude}`` (m).
    """
    offset = np.asarray(heights, dtype=np.float64) - HALF
    return {"rest_offset": float(np.mean(offset)), "rest_error": float(np.max(np.abs(offset)))}


def stack_metrics(initial_top, final_top, rest_height: float) -> dict:
    """Sink and drift of the top box from (batch, dim) positions.

    Sink is the mean of ``rest_height`` (the top box's height with every box
    exactly touching, the closed form) minus its final height, so the 0–1 mm
    that :func:`world_shifts` lifts a batched world by is not counted as
    sinking; drift is the largest sideways move from each world's own start.
    It stands when every world's top box is finite, drifted less than
    :data:`STAND_DRIFT` and ended within :data:`STAND_SINK` of the rest height,
    below or above (a column thrown straight up moves no sideways).

    Args:
        initial_top: (batch, dim) the top box's centre at the start (m).
        final_top: (batch, dim) its centre at the end (m).
        rest_height: the top box's height with every box touching (m).

    Returns:
        ``{"sink": mean fall (m), "drift": largest sideways move (m), "stands": bool}``.
    """
    initial_top, final_top = np.asarray(initial_top), np.asarray(final_top)
    fall = rest_height - final_top[:, -1]  # per world
    drift = float(np.max(np.linalg.norm(final_top[:, :-1] - initial_top[:, :-1], axis=-1)))
    stands = (bool(np.all(np.isfinite(final_top))) and drift < STAND_DRIFT
              and bool(np.all(np.abs(fall) < STAND_SINK)))
    return {"sink": float(np.mean(fall)), "drift": drift, "stands": stands}


def time_jax(fn: Callable, *args, settings: dict):
    """Compile ``fn`` and time its calls as every engine's jitted code is timed here.

    Args:
        fn: the function to jit.
        *args: its arguments.
        settings: the section's (``peers_repeats``, ``peers_budget_s``).

    Returns:
        :class:`jaxrb.bench.timing.Timing` (``compile_s``, ``run_s``, ``output``).
    """
    return time_jitted(fn, *args, repeats=settings["peers_repeats"], min_repeats=1,
                       budget_s=settings["peers_budget_s"])
