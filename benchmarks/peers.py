"""Peers side by side: jaxrb against MuJoCo (C), MJX, Brax, Jax2D and pymunk in one run.

This module runs the section and writes its Markdown; its parts are
:mod:`benchmarks.scenes` (the scenes, jaxrb's settings for them and the
:class:`~benchmarks.scenes.PeerRow` every run returns),
:mod:`benchmarks.jaxrb_runs` (jaxrb's rows), :mod:`benchmarks.peer_runs` (the
peers' rows), :mod:`benchmarks.peer_gradients` (the gradient scene) and
:mod:`benchmarks.targets` (the issues' targets).

Every peer is optional: :func:`benchmarks.peer_runs.load_peers` imports it
inside ``try`` and a peer that is absent or fails is skipped with a note
saying why (``pip install -e ".[peers]"`` brings them in). The scenes are the
ones jaxrb's own benchmarks use (:mod:`jaxrb.bench.contact`,
:mod:`jaxrb.bench.free_body`); the peers get the same bodies, built as MJCF
strings (MuJoCo, MJX, Brax) or with the peer's own scene API (Jax2D, pymunk):

* **drop**: a 0.2 m box (1 kg) released with its centre at 0.5 m above a
  plane, friction 0.5. Peers step at h = 2 ms; jaxrb runs its own best setting
  (impulse contact, dt = 1/60 s, 4 substeps) *and* h = 2 ms (1 substep) with
  impulse and with penalty contact (:data:`benchmarks.scenes.DROP_JAXRB`).
  Figures: body-steps/s at a batch of worlds, compile time, and the resting
  height z − 0.1 m after the rollout (mean over worlds; its largest
  magnitude is what the target checks).
* **stack**: 10 boxes in a column on the plane for ``peers_stack_seconds``;
  *sink* = how far the top box ends below its height with every box
  exactly touching (mean over worlds; a batched world starts lifted by
  0–1 mm, which is not sinking), *drift* = horizontal displacement of the
  top box at the end (largest over worlds). jaxrb runs it with impulse
  contact at dt = 1/60 s with 8 substeps and a 12-pair broadphase
  (:data:`benchmarks.scenes.STACK_BUILD`), and with penalty contact at
  h = 0.5 ms with the spring of ``STACK_PENALTY_FREQUENCY``
  (:data:`benchmarks.scenes.STANDING_SETTINGS`; the same broadphase). Every engine starts from the same column, each box set
  off sideways by up to 1 mm (:func:`jaxrb.bench.contact.column_centres`).
* **pyramid**: the 55-box 2D pyramid (10 rows, 5 % gaps, μ = 0.5), jaxrb
  against Jax2D at the same batch and pymunk in one world; *stands* = the top
  box moved less than 1 cm sideways and sank less than half a box (and, for
  jaxrb, its broadphase never ran out of pairs). jaxrb runs it with impulse
  contact at its own setting and with penalty contact at h = 2 ms, both with
  a 150-pair broadphase (``scenes.PYRAMID_BUILD``); the peers step at 1/60 s
  (body-s/s compares across step sizes).

  Every jaxrb setting of a scene is a row of its own and is checked against
  every target of the scene (:func:`benchmarks.targets.evaluate_targets`).
* **flip**: the torque-free intermediate-axis flip (inertia (0.3, 0.35,
  0.4) kg m², ω0 = (0.1, 15, 0.1) rad/s): largest flip-time error against
  :func:`jaxrb.analytic.flip_times` for MuJoCo C's RK4 (float64), MJX's RK4
  (float32) and jaxrb's best integrator (float32 and float64) at each h.
* **gradient**: the drop's gradient in one world (and, against Brax spring,
  in a batch of worlds), jaxrb against the peers
  that differentiate (MJX, Brax): forward and gradient time, whether every
  entry is finite, and the loss (:mod:`benchmarks.peer_gradients`).

Timing is :func:`jaxrb.bench.timing.time_jitted` for everything jitted
(:func:`benchmarks.scenes.time_jax`: compile apart, then the median of calls after a warm-up, with
``block_until_ready``); MuJoCo C is timed with ``time.perf_counter`` around
``mj_step`` calls from Python (one world) and around ``mujoco.rollout`` (a
loop over worlds in C, one thread). Peers' JAX code runs with x64 disabled
so that they compute in float32 like jaxrb's throughput runs.

Where ``import jaxrb`` set LLVM's unroll limit (:data:`jaxrb.compile.UNROLL_LIMIT_OPTION`),
each scene's peers run in a child process whose ``XLA_FLAGS`` are this
process's without it (:func:`peer_process_flags`): LLVM options hold for a
whole process, and the limit slowed Brax spring's batched drop by about 6 %
(docs/design.md, 'XLA and LLVM options'). jaxrb's rows of the scene run here first,
then the child's; the loop threshold stays in both, as in the reports before.

Settings (:data:`QUICK`, :data:`FULL`; every key starts with ``peers_``):
``scenes`` and ``engines`` to run; ``drop_batch``/``drop_steps`` and
``drop_jaxrb`` (jaxrb's (contact, dt, substeps) settings); ``mujoco_worlds`` (worlds in
MuJoCo's C rollout loop); ``stack_batch``/``stack_seconds``/``stack_mjx`` and
``stack_jaxrb`` (jaxrb's contact models, see ``scenes.STANDING_SETTINGS``);
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

import math
import os
import pickle
import subprocess
import sys
import tempfile
from typing import Callable, Dict, List, Optional, Sequence, Tuple

import jax.numpy as jnp

from benchmarks import jaxrb_runs, peer_gradients, peer_runs
from benchmarks.scenes import (DROP_CENTRE, DROP_JAXRB, ENGINE_NAMES, ENGINES, FRICTION, PYMUNK_TARGET_BATCH,
                               SCENE_TITLES, STACK_COUNT, STAND_DRIFT, STAND_SINK, PeerRow, ratio)
from benchmarks.targets import evaluate_targets, targets_table
from jaxrb import analytic
from jaxrb import compile as rb_compile
from jaxrb.bench import free_body
from jaxrb.bench.report import fmt_fixed, fmt_sci, fmt_si, fmt_step, markdown_table

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
    modules, skipped = peer_runs.load_peers(settings["peers_engines"])
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
                attempt("jaxrb", "drop", lambda m=model, d=dt, n=substeps, f=form: jaxrb_runs.jaxrb_drop(
                    m, d, n, batch, steps, settings, f))
        attempt("mujoco", "drop", lambda: peer_runs.mujoco_drop(modules["mujoco"], steps,
                                                                settings["peers_mujoco_worlds"], settings))
        attempt("mjx", "drop", lambda: peer_runs.mjx_drop(modules["mjx"], batch, steps, settings))
        for engine in ("brax_spring", "brax_positional"):
            attempt(engine, "drop", lambda e=engine: peer_runs.brax_drop(e, modules[e], batch, steps, settings))
    if "stack" in scenes:
        batch, seconds = settings["peers_stack_batch"], settings["peers_stack_seconds"]
        for model in settings["peers_stack_jaxrb"]:
            attempt("jaxrb", "stack", lambda m=model: jaxrb_runs.jaxrb_stack(m, batch, seconds, settings))
        attempt("mujoco", "stack", lambda: peer_runs.mujoco_stack(modules["mujoco"], seconds, settings))
        attempt("brax_spring", "stack", lambda: peer_runs.brax_stack("brax_spring", modules["brax_spring"], batch,
                                                                     seconds, settings))
        if settings["peers_stack_mjx"]:
            attempt("mjx", "stack", lambda: peer_runs.mjx_stack(modules["mjx"], batch, seconds, settings))
    if "pyramid" in scenes:
        batch, seconds = settings["peers_pyramid_batch"], settings["peers_pyramid_seconds"]
        big_batch, big_seconds = settings["peers_pyramid_big_batch"], settings["peers_pyramid_big_seconds"]
        for model in settings["peers_pyramid_jaxrb"]:
            attempt("jaxrb", "pyramid", lambda m=model: jaxrb_runs.jaxrb_pyramid(m, batch, seconds, settings))
            if big_batch:
                attempt("jaxrb", "pyramid", lambda m=model: jaxrb_runs.jaxrb_pyramid(m, big_batch, big_seconds,
                                                                                      settings))
        attempt("jax2d", "pyramid", lambda: peer_runs.jax2d_pyramid(modules["jax2d"], batch, seconds, settings))
        attempt("pymunk", "pyramid", lambda: peer_runs.pymunk_pyramid(modules["pymunk"], seconds, settings))
    if "flip" in scenes:
        horizon = settings["peers_flip_horizon"]
        reference = analytic.flip_times(free_body.TUMBLE_INERTIA, free_body.TUMBLE_ANGVEL, horizon)
        for h in settings["peers_flip_steps"]:
            for integrator, orientation in settings["peers_flip_configs"]:
                for dtype in (jnp.float32, jnp.float64):
                    attempt("jaxrb", "flip", lambda i=integrator, o=orientation, d=dtype, hh=h:
                            jaxrb_runs.jaxrb_flip(i, o, hh, horizon, d, reference, settings))
            attempt("mujoco", "flip", lambda hh=h: peer_runs.mujoco_flip(modules["mujoco"], hh, horizon, reference,
                                                                         settings))
            if settings["peers_flip_mjx"]:
                attempt("mjx", "flip", lambda hh=h: peer_runs.mjx_flip(modules["mjx"], hh, horizon, reference,
                                                                       settings))
    if "gradient" in scenes:
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
