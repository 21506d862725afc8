"""Contact throughput: compile and run time of contact scenes, impulse and penalty models.

Scenes (the settings of ``tests/test_contact.py`` and ``tests/test_stacks.py``):

* **bounce**: sphere r = 0.1 m dropped from 1 m on a plane, restitution 0.8
  (impulse dt = 1/240 s, 4 substeps; penalty dt = 1e-3 s).
* **slide**: box (half 0.1 m, 1 kg) at v0 = 2 m/s on a plane, μ = 0.5
  (impulse dt = 1/60 s, 4 substeps; penalty dt = 1e-3 s).
* **drop**: box (half 0.1 m) released with its centre at 0.5 m onto a plane,
  impulse dt = 1/60 s, 4 substeps; also its resting height error |z − 0.1 m|
  after 1 s (batch 1, float32).
* **stack3d**: 10 boxes in a 3D column, each set off sideways by up to
  :data:`COLUMN_JITTER` (impulse dt = 1/60 s, 4 substeps; penalty dt = 1e-3 s).
* **pyramid2d**: 55-box 2D pyramid, 10 rows (impulse dt = 1/60 s,
  4 substeps; penalty dt = 1e-3 s).

Everything runs in float32. ``num_steps`` steps run as ``rb.rollout`` runs
them, inside one jit (final state only, :func:`jaxrb.bench.timing.final_state_fn`).
Larger batches ``jax.vmap`` that over initial states that differ by a tiny
per-world shift of every body (±1 mm horizontally, 0–1 mm up).
Times come from :func:`jaxrb.bench.timing.time_jitted`. Every reported figure
is checked to be finite (:func:`check_finite`).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Optional, Sequence

import jax
import jax.numpy as jnp
import numpy as np

import jaxrb as rb
from jaxrb.bench.report import fmt_fixed, fmt_sci, fmt_si, fmt_step, markdown_table
from jaxrb.bench.timing import final_state_fn, time_jitted
from jaxrb.compile import jit
from jaxrb.model.options import grouped

HALF = 0.1
DROP_CENTRE = 0.5  # m, initial centre height of the dropped box
RESTING_HEIGHT = HALF


def bounce_scene():
    scene = rb.Scene(dim=3)
    scene.add_plane(restitution=0.8)
    scene.add_body(rb.Sphere(0.1), mass=1.0, pos=(0.0, 0.0, 1.0), restitution=0.8)
    return scene


def slide_scene():
    scene = rb.Scene(dim=3)
    scene.add_plane(friction=0.5)
    scene.add_body(rb.Box((HALF,) * 3), mass=1.0, pos=(0.0, 0.0, HALF), vel=(2.0, 0.0, 0.0),
                   friction=0.5)
    return scene


def drop_scene():
    scene = rb.Scene(dim=3)
    scene.add_plane()
    scene.add_body(rb.Box((HALF,) * 3), mass=1.0, pos=(0.0, 0.0, DROP_CENTRE))
    return scene


#: Largest sideways offset (m) of a column's box from the vertical: a column
#: stacked by hand to within a millimetre. An exactly aligned column keeps its
#: symmetry in exact arithmetic, so a setting can look stable only because
#: nothing breaks it: the penalty column at h = 1 ms with a spring twice the
#: default stood aligned on a CPU, fell on a GPU (different rounding) and, with
#: these offsets, drifted 2–24 mm in 1 s on the CPU too.
COLUMN_JITTER = 1e-3


def column_centres(count: int, dim: int = 3, seed: int = 0) -> np.ndarray:
    """Centres of ``count`` touching 0.2 m boxes, each set off sideways by up to :data:`COLUMN_JITTER`.

    Args:
        count: boxes, bottom first.
        dim: 2 or 3.
        seed: the offsets' random draw (fixed, so every engine gets the same column).

    Returns:
        (count, dim) centres (m); the last axis is up.
    """
    offsets = np.random.default_rng(seed).uniform(-COLUMN_JITTER, COLUMN_JITTER, size=(count, dim - 1))
    heights = HALF + 2 * HALF * np.arange(count)
    return np.concatenate([offsets, heights[:, None]], axis=1)


def column_scene(masses, dim: int = 3):
    """A column of 0.2 m cubes (squares in 2D) on a plane, μ = 0.5; ``masses`` (kg) from the ground up.

    The boxes stand at :func:`column_centres`, so a column cannot stand by
    symmetry alone.
    """
    scene = rb.Scene(dim=dim)
    scene.add_plane(friction=0.5)
    for mass, centre in zip(masses, column_centres(len(masses), dim)):
        scene.add_body(rb.Box((HALF,) * dim), mass=float(mass), pos=tuple(centre), friction=0.5)
    return scene


def stack3d_scene(count: int = 10):
    return column_scene([1.0] * count)


def pyramid2d_scene(rows: int = 10):
    scene = rb.Scene(dim=2)
    scene.add_plane(friction=0.5)
    for row in range(rows):
        for column in range(rows - row):
            x = (column - (rows - 1 - row) / 2.0) * 2 * HALF * 1.05
            scene.add_body(rb.Box((HALF, HALF)), mass=1.0, pos=(x, HALF + 2 * HALF * row),
                           friction=0.5)
    return scene


IMPULSE = dict(dt=1 / 60, substeps=4)
PENALTY = dict(dt=1e-3, substeps=1)

#: name -> (scene factory, description, {contact model: build settings}, large-batch kind)
SCENES = {
    "bounce": (bounce_scene, "sphere r=0.1 dropped from 1 m, e=0.8",
               {"impulse": dict(dt=1 / 240, substeps=4), "penalty": PENALTY}, "large"),
    "slide": (slide_scene, "box half 0.1, 1 kg, v0=2 m/s, μ=0.5",
              {"impulse": IMPULSE, "penalty": PENALTY}, "large"),
    "drop": (drop_scene, f"box half 0.1 dropped from z={DROP_CENTRE} m",
             {"impulse": IMPULSE}, "large"),
    "stack3d": (stack3d_scene, "10-box 3D column", {"impulse": IMPULSE, "penalty": PENALTY}, "small"),
    "pyramid2d": (pyramid2d_scene, "55-box 2D pyramid", {"impulse": IMPULSE, "penalty": PENALTY},
                  "small"),
}


def _batched_state(state, batch: int, seed: int = 1):
    """``batch`` copies of ``state``, each world's bodies shifted together by a tiny offset."""
    rng = np.random.default_rng(seed)
    batched = jax.tree_util.tree_map(lambda a: jnp.broadcast_to(a, (batch,) + a.shape), state)
    dim = state.pos.shape[-1]
    shift = np.concatenate([rng.uniform(-1e-3, 1e-3, size=(batch, dim - 1)),
                            rng.uniform(0.0, 1e-3, size=(batch, 1))], axis=1)
    return batched.replace(pos=batched.pos + jnp.asarray(shift[:, None, :], state.pos.dtype))


@dataclasses.dataclass
class ContactResult:
    scene: str
    contact: str
    dt: float
    substeps: int
    batch: int
    num_bodies: int
    num_steps: int
    compile_s: float
    run_s: float
    rest_error: Optional[float] = None

    @property
    def body_steps_per_s(self) -> float:
        return self.batch * self.num_bodies * self.num_steps / self.run_s


def check_finite(result: ContactResult, final_pos) -> None:
    """Sanity check (no test needed): every figure and the final positions are finite."""
    figures = [result.compile_s, result.run_s, result.body_steps_per_s]
    if result.rest_error is not None:
        figures.append(result.rest_error)
    if not all(math.isfinite(float(v)) for v in figures) or \
            not bool(jnp.all(jnp.isfinite(final_pos))):
        raise FloatingPointError(f"contact bench {result.scene}/{result.contact} batch "
                                 f"{result.batch}: non-finite figure or state ({figures})")


def resting_height_error(model, params, state, seconds: float = 1.0) -> float:
    """|z − 0.1 m| of the dropped box after ``seconds`` (batch 1)."""
    num_steps = int(round(seconds / float(params.dt)))
    final = jit(final_state_fn(rb.make_step(model), num_steps))(state, params)
    return abs(float(final.pos[0, -1]) - RESTING_HEIGHT)


def run_contact(name: str, contact: str, batch: int, num_steps: int, repeats: int = 5,
                dtype=jnp.float32) -> ContactResult:
    factory, _, settings, _ = SCENES[name]
    build = settings[contact]
    model, params, state = factory().build(**grouped(dict(build, contact=contact, dtype=dtype)))
    step = rb.make_step(model)
    num_bodies = int(state.pos.shape[0])
    rest_error = None
    if name == "drop" and batch == 1:
        rest_error = resting_height_error(model, params, state)
    if batch > 1:
        state = _batched_state(state, batch)
    timing = time_jitted(final_state_fn(step, num_steps, batch > 1), state, params, repeats=repeats,
                         budget_s=5.0)
    result = ContactResult(name, contact, float(build["dt"]), int(build["substeps"]), batch,
                           num_bodies, num_steps, timing.compile_s, timing.run_s, rest_error)
    check_finite(result, timing.output.pos)
    return result


def contact_section(scenes: Sequence[str], large_batch: int, small_batch: int, num_steps: int,
                    repeats: int = 5, log=None):
    """Run the contact throughput benchmark; return ``(markdown, results)``."""
    log = log or (lambda text: None)
    results = []
    for name in scenes:
        _, _, settings, kind = SCENES[name]
        for contact in settings:
            for batch in (1, large_batch if kind == "large" else small_batch):
                r = run_contact(name, contact, batch, num_steps, repeats=repeats)
                log(f"contact {name:>9} {contact:>7} batch {batch:>5}: compile {r.compile_s:.2f} s, "
                    f"run {r.run_s:.3f} s, {fmt_si(r.body_steps_per_s, ' body-steps/s')}")
                results.append(r)
    lines = [
        "Scenes: " + "; ".join(f"**{n}**: {SCENES[n][1]}" for n in scenes) + ". "
        f"float32; {num_steps} steps of `rb.rollout` inside one jit (final state only); "
        "larger batches are `jax.vmap` of it over initial states shifted by a tiny per-world "
        "offset (±1 mm horizontally, 0–1 mm up). "
        "*compile* = trace + lower + compile; *run* = median wall time of the whole scan with "
        "block_until_ready; body-steps/s = batch · bodies · steps / run (a step includes its "
        "substeps). *rest err* = |z − 0.1 m| of the dropped box after 1 s (batch 1). "
        "Every figure is checked finite.",
        "",
        markdown_table(
            ["scene", "contact", "dt (s)", "substeps", "bodies", "batch", "compile (s)",
             "run (s)", "µs/step", "body-steps/s", "rest err (m)"],
            [[r.scene, r.contact, fmt_step(r.dt), r.substeps, r.num_bodies, r.batch,
              fmt_fixed(r.compile_s, 2), fmt_fixed(r.run_s, 4),
              fmt_fixed(1e6 * r.run_s / r.num_steps, 1), fmt_si(r.body_steps_per_s),
              fmt_sci(r.rest_error) if r.rest_error is not None else "—"] for r in results],
            align=["l", "l", "r", "r", "r", "r", "r", "r", "r", "r", "r"]),
    ]
    return "\n".join(lines), results
