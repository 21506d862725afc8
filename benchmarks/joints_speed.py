"""Joints speed: a 10-link hinge chain and gymnasium's ant, jaxrb beside Brax and MJX, at two vector widths.

The issue "Joints" asks for the speed of scenes with joints: a 10-link hinge
chain (no contact) and gymnasium's ``ant`` in the air, at 1 and 1 024 worlds,
ahead of every Brax pipeline that loads them and at least 10× MJX, in
body-steps/s and simulated seconds per second; the ant on its floor measured
and reported; compile at most 5 s. This section measures those figures on
the host it runs on, at the host's full vector width and again at AVX2
(``--xla_cpu_max_isa=AVX2``), and writes them as ratios in one report.

**Models** (:data:`MODELS`), the same model in every engine:

* ``chain``: 10 capsules (0.1 m long, radius 0.01 m, 1 kg each) hinged end to
  end about y, the first to the world at the origin, released horizontal along
  +x (:func:`chain_scene` in jaxrb, :func:`chain_mjcf` for the others).
  Contact off.
* ``ant_air``: gymnasium's ``ant.xml`` (``gymnasium/envs/mujoco/assets``): jaxrb
  reads it with ``rb.load_scene`` and builds it with ``contact="none",
  substeps=1``; MJX and Brax read the file with ``integrator="Euler"`` (Brax
  cannot load its ``RK4``: "Only euler integration is supported") and
  ``<flag contact="disable"/>``, which both honour.
* ``ant_floor``: the same file as it is, on its floor: jaxrb's ``found.build()``
  (impulse contact, the file's dt = 0.01 s in 10 substeps) beside MJX's Euler
  with its contacts (and Brax's pipelines where ``joints_floor_engines`` asks).

Every engine steps at the file's dt (the chain's 0.01 s too), float32, for the
same number of steps, from the same start: MuJoCo's ``qpos0`` (for the ant
gymnasium's reset pose, torso at 0.75 m, every joint at 0) with zero
velocity; a batch's worlds differ by hinge angles drawn in ±0.01 rad
(:func:`initial_qpos`). The ant's eight motors hold the constant controls
:data:`ANT_CONTROLS` (×150 gear), so its legs move and meet their limits.
jaxrb runs both its joint integrators: ``semi_implicit`` (MuJoCo's Euler, the
scheme Brax generalized and MJX use here) and ``midpoint`` (its default).

**Timing** (:mod:`jaxrb.bench.timing`): every engine's program is a
``fori_loop`` over ``steps`` calls of its step (``jax.vmap``-ed over the
worlds at a batch > 1): jaxrb's is the loop a user writes around
``rb.make_step``, MJX's ``mjx.step``, Brax's ``pipeline.step``. Each is
compiled apart (trace + lower + compile, :func:`jaxrb.bench.timing.compile_jitted`);
then the programs of one model and batch are called in turn, one call each a
round (after one untimed round), and each figure is the median over rounds
with ``block_until_ready``: a slow spell of the shared host hits every engine
alike. As in :mod:`benchmarks.peers`, the peers run in a child process whose
``XLA_FLAGS`` lack jaxrb's LLVM unroll limit (:func:`benchmarks.peers.peer_process_flags`);
here that child stays up and takes its turn in every round (:class:`_ChildSession`),
so the alternation crosses the two processes, one of them idle while the other
runs. body-steps/s = worlds · bodies · steps / run (a jaxrb step includes its
substeps); body-s/s = body-steps/s · dt. Bodies are the model's moving
bodies: 10 for the chain in every engine, 13 for the ant (jaxrb's and
MuJoCo's count; Brax's system fuses the four jointless leg roots into the
torso and has 9 links, but it simulates the same ant, so its rows count 13).

**Widths** (``joints_widths``): ``"native"`` runs in this process with its
``XLA_FLAGS``; ``"avx2"`` runs the whole section again in a child interpreter
whose ``XLA_FLAGS`` add ``--xla_cpu_max_isa=AVX2`` (and its peers' child
inherits it). XLA's CPU backend prefers 256-bit vectors either way
(LLVM's ``prefer-vector-width=256``), so on an AVX-512 host the widths differ
in the instructions LLVM may pick (AVX-512's masks and 32 vector
registers), not in the vector length.

Settings (:data:`QUICK`, :data:`FULL`; every key starts with ``joints_``):
``models``; ``engines`` (air models) and ``floor_engines`` (``ant_floor``);
``integrators`` (jaxrb's); ``batches`` and ``floor_batches`` ((worlds, steps)
pairs); ``widths``; ``repeats`` (timed rounds at most), ``min_repeats`` and
``budget_s`` (the rounds stop once this many seconds of calls are spent and
``min_repeats`` rounds are done); ``peer_timeout_s`` (a peers' process that
answers nothing for this long is ended, its group's peers are a note, and a
new process takes the next group); ``mjx_chain_links`` and ``mjx_cap_s``
(below).

**MJX on the chain**: on this CPU one ``mjx.step`` of a hinge chain costs
time that grows about 20-fold with each link past 8 (0.8 s at 8 links,
19 s at 9, more than 190 s at 10, after compiling in 6-8 s; mujoco 4.0.1,
jax 0.10.2), so the chain's timed groups leave MJX out and
:func:`mjx_chain_probe` times one compiled ``mjx.step`` at one world for
each length of ``mjx_chain_links`` instead, each in a process of its own
that is ended after ``mjx_cap_s`` seconds of calling. A length that runs
out of time gives a lower bound on MJX's time per step, and the chain's
MJX target is judged on it at one world (at 1 024 worlds MJX is not timed).
"""

from __future__ import annotations

import dataclasses
import math
import os
import pickle
import select
import statistics
import subprocess
import sys
import tempfile
import threading
import time
import warnings
from typing import Any, Callable, Dict, List, Optional, Sequence, Tuple

import jax
import jax.numpy as jnp
import numpy as np

from benchmarks import peer_runs, peers
from benchmarks.scenes import PeerRow, ratio, x64
from jaxrb.bench.report import cpuinfo, fmt_fixed, fmt_si, markdown_table
from jaxrb.bench.timing import compile_jitted

#: The models, in report order.
MODELS = ("chain", "ant_air", "ant_floor")
MODEL_TITLES = {"chain": "10-link hinge chain, no contact", "ant_air": "gymnasium ant in the air (contact off)",
                "ant_floor": "gymnasium ant on its floor"}
#: Every engine the section knows, in report order.
ENGINES = ("jaxrb", "mjx", "brax_generalized", "brax_positional", "brax_spring")
ENGINE_NAMES = {"jaxrb": "jaxrb", "mjx": "MJX", "brax_generalized": "Brax generalized",
                "brax_positional": "Brax positional", "brax_spring": "Brax spring"}
BRAX_ENGINES = ("brax_generalized", "brax_positional", "brax_spring")
#: jaxrb's joint integrators the section runs by default.
INTEGRATORS = ("semi_implicit", "midpoint")
#: The vector widths: a name -> the entry added to XLA_FLAGS (None: this process as it is).
WIDTHS = {"native": None, "avx2": "--xla_cpu_max_isa=AVX2"}

CHAIN_LINKS = 10
CHAIN_LENGTH = 0.1  # m, each link
CHAIN_RADIUS = 0.01  # m
CHAIN_MASS = 1.0  # kg, each link
CHAIN_DT = 0.01  # s
GRAVITY = 9.81
#: The ant's constant controls (its motors' ctrlrange is ±1, gear 150): the legs move and reach their limits.
ANT_CONTROLS = (0.5, -0.5, 0.5, -0.5, 0.5, -0.5, 0.5, -0.5)
#: Half-width (rad) of the per-world hinge-angle draws of a batch.
WORLD_SPREAD = 0.01
#: Target: jaxrb at least this many times MJX's body-steps/s.
MJX_FACTOR = 10.0
#: Target: compile at most this many seconds.
COMPILE_TARGET_S = 5.0

#: QUICK: the chain alone, at 1 and 8 worlds, jaxrb beside MJX and Brax
#: generalized, at the native width: a smoke run (about 30 s idle on 2 cores,
#: mostly compiling and the peers' process starting).
QUICK = dict(
    joints_models=("chain",), joints_engines=("jaxrb", "mjx", "brax_generalized"),
    joints_floor_engines=("jaxrb", "mjx"), joints_integrators=INTEGRATORS,
    joints_batches=((1, 50), (8, 20)), joints_floor_batches=((1, 10), (8, 5)),
    joints_widths=("native",), joints_repeats=2, joints_min_repeats=1, joints_budget_s=1.0,
    joints_mjx_chain_links=(4, 6), joints_mjx_cap_s=30.0, joints_peer_timeout_s=300.0,
)
#: FULL: every model at 1 and 1 024 worlds, every engine, both widths.
FULL = dict(
    joints_models=MODELS, joints_engines=ENGINES, joints_floor_engines=("jaxrb", "mjx"),
    joints_integrators=INTEGRATORS,
    joints_batches=((1, 100), (1024, 100)), joints_floor_batches=((1, 500), (1024, 20)),
    joints_widths=("native", "avx2"), joints_repeats=7, joints_min_repeats=3, joints_budget_s=12.0,
    joints_mjx_chain_links=(6, 7, 8, 9, 10), joints_mjx_cap_s=60.0, joints_peer_timeout_s=300.0,
)


# --- the models -----------------------------------------------------------------------------

def ant_path() -> str:
    """gymnasium's ``ant.xml`` (ImportError where gymnasium is not installed)."""
    import gymnasium

    return os.path.join(os.path.dirname(gymnasium.__file__), "envs", "mujoco", "assets", "ant.xml")


def ant_mjcf(contact: bool) -> str:
    """The ant file for MJX and Brax: integrator Euler; ``contact=False`` adds ``<flag contact="disable"/>``."""
    with open(ant_path()) as handle:
        text = handle.read()
    option = '<option integrator="RK4" timestep="0.01"/>'
    if option not in text:
        raise ValueError(f"{ant_path()}: expected {option!r}; the file changed")
    flag = "" if contact else '<flag contact="disable"/>'
    return text.replace(option, f'<option integrator="Euler" timestep="0.01">{flag}</option>')


def chain_mjcf(links: int = CHAIN_LINKS) -> str:
    """MJCF of :func:`chain_scene`'s chain: nested bodies, a y hinge at each link's start, contact disabled."""
    body = ""
    for i in reversed(range(links)):
        position = "0 0 0" if i == 0 else f"{CHAIN_LENGTH!r} 0 0"
        body = (f'<body name="link{i}" pos="{position}"><joint name="hinge{i}" type="hinge" axis="0 1 0"/>'
                f'<geom type="capsule" fromto="0 0 0 {CHAIN_LENGTH!r} 0 0" size="{CHAIN_RADIUS!r}" '
                f'mass="{CHAIN_MASS!r}"/>{body}</body>')
    return (f'<mujoco model="jaxrb_chain{links}">\n'
            f'  <option timestep="{CHAIN_DT!r}" gravity="0 0 -{GRAVITY!r}" integrator="Euler">'
            f'<flag contact="disable"/></option>\n'
            f'  <worldbody>{body}</worldbody>\n</mujoco>')


def chain_scene(links: int = CHAIN_LINKS):
    """jaxrb's chain: capsules along +x from the origin, each hinged about y at its start to the one before."""
    import jaxrb as rb

    scene = rb.Scene(dim=3, gravity=(0.0, 0.0, -GRAVITY))
    along_x = rb.quaternion.from_axis_angle(jnp.asarray([0.0, 1.0, 0.0]), math.pi / 2)  # body z onto world x
    previous = None
    for i in range(links):
        body = scene.add_body(rb.Capsule(radius=CHAIN_RADIUS, half_length=CHAIN_LENGTH / 2), mass=CHAIN_MASS,
                              pos=(CHAIN_LENGTH * (i + 0.5), 0.0, 0.0), quat=np.asarray(along_x))
        scene.add_joint(rb.Hinge(axis=(0, 1, 0), anchor=(CHAIN_LENGTH * i, 0.0, 0.0)), body, previous)
        previous = body
    return scene


def jaxrb_build(model_name: str, integrator: str):
    """``(model, params, state)`` of jaxrb's ``model_name`` with ``integrator``, float32."""
    import jaxrb as rb

    if model_name == "chain":
        return chain_scene().build(dt=CHAIN_DT, integrator=integrator, contact="none", dtype=jnp.float32)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        found = rb.load_scene(ant_path())
    if model_name == "ant_air":
        return found.build(contact="none", substeps=1, integrator=integrator, dtype=jnp.float32)
    if model_name == "ant_floor":
        return found.build(integrator=integrator, dtype=jnp.float32)
    raise ValueError(f"joints: unknown model {model_name!r}; valid: {', '.join(MODELS)}")


def peer_mjcf(model_name: str) -> str:
    """The MJCF that MJX and Brax read for ``model_name``."""
    if model_name == "chain":
        return chain_mjcf()
    return ant_mjcf(contact=model_name == "ant_floor")


def num_bodies(model_name: str) -> int:
    """Moving bodies counted for every engine (module docstring)."""
    return CHAIN_LINKS if model_name == "chain" else 13


def controls(model_name: str) -> Optional[np.ndarray]:
    """The model's constant controls, or None (the chain has no actuators)."""
    return None if model_name == "chain" else np.asarray(ANT_CONTROLS, np.float32)


def initial_qpos(qpos0: np.ndarray, hinge_slots: Sequence[int], batch: int, seed: int = 1) -> np.ndarray:
    """(batch, nq) start coordinates: ``qpos0`` for one world; at a batch, hinge angles drawn in ±WORLD_SPREAD.

    Args:
        qpos0: (nq,) MuJoCo's qpos0 of the model.
        hinge_slots: the qpos indices of the hinges.
        batch: worlds.
        seed: NumPy generator seed (the same draws for every engine).
    """
    qpos = np.tile(np.asarray(qpos0, np.float64), (batch, 1))
    if batch > 1:
        rng = np.random.default_rng(seed)
        qpos[:, list(hinge_slots)] += rng.uniform(-WORLD_SPREAD, WORLD_SPREAD, size=(batch, len(hinge_slots)))
    return qpos


def _mujoco_layout(model_name: str):
    """(qpos0, hinge qpos indices) from MuJoCo's compile of the peers' MJCF."""
    import mujoco

    compiled = mujoco.MjModel.from_xml_string(peer_mjcf(model_name))
    hinges = [int(compiled.jnt_qposadr[j]) for j in range(compiled.njnt)
              if compiled.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE]
    return np.asarray(compiled.qpos0, np.float64), hinges


# --- programs -------------------------------------------------------------------------------

@dataclasses.dataclass
class _Program:
    """One compiled engine program of a group: its row (run_s still 0), a call and a read-out of its output."""

    row: PeerRow
    call: Callable[[], Any]
    read: Callable[[Any], np.ndarray]  # output -> (batch, nq) final qpos
    runs: List[float] = dataclasses.field(default_factory=list)
    output: Any = None


def _loop(advance: Callable, steps: int) -> Callable:
    """``(state, model) -> state`` after ``steps`` calls of ``advance(state, model)`` in a ``fori_loop``."""
    return lambda state, model: jax.lax.fori_loop(0, steps, lambda _, s: advance(s, model), state)


def _compiled_program(row: PeerRow, fn: Callable, state, model_arg, read: Callable) -> _Program:
    compiled, compile_s = compile_jitted(fn, state, model_arg)
    row.compile_s = compile_s
    return _Program(row=row, call=lambda: compiled(state, model_arg), read=read)


def jaxrb_program(model_name: str, integrator: str, batch: int, steps: int, width: str) -> _Program:
    """jaxrb's user loop over ``vmap(step)`` (``step`` alone at one world) for ``model_name``."""
    import jaxrb as rb

    with x64(False):
        model, params, state = jaxrb_build(model_name, integrator)
        step = rb.make_step(model)
        qpos0, hinges = _mujoco_layout(model_name)
        if model_name != "chain":
            np.testing.assert_allclose(np.asarray(state.qpos), qpos0, atol=1e-6)  # loaded as MuJoCo compiles it
        qpos = jnp.asarray(initial_qpos(qpos0, hinges, batch), jnp.float32)
        zero = jnp.zeros_like(state.qvel)
        states = jax.vmap(lambda q: rb.joints.set_qpos_qvel(model, params, state, q, zero))(qpos)
        ctrl = controls(model_name)
        ctrl = None if ctrl is None else jnp.asarray(ctrl)
        one = lambda s, p: step(s, p, None, ctrl)
        if batch == 1:
            states = jax.tree_util.tree_map(lambda a: a[0], states)
            advance = one
        else:
            advance = jax.vmap(one, in_axes=(0, None))
        setting = f"{integrator}, dt {params.dt:g} s" + (f" × {model.substeps}" if model.substeps > 1 else "") + \
            (f", {model.contact} contact" if model.contact != "none" else "")
        row = PeerRow(model_name, "jaxrb", setting, float(params.dt), batch, num_bodies(model_name), steps, None,
                      0.0, {"width": width, "integrator": integrator})
        return _compiled_program(row, _loop(advance, steps), states, params,
                                 lambda out: np.asarray(out.qpos, np.float64).reshape(batch, -1))


def mjx_program(mods: dict, model_name: str, batch: int, steps: int, width: str) -> _Program:
    """MJX's ``fori_loop`` over ``vmap(mjx.step)`` (``mjx.step`` at one world), Euler, float32."""
    mujoco, mjx = mods["mujoco"], mods["mjx"]
    with x64(False):
        compiled_model = mujoco.MjModel.from_xml_string(peer_mjcf(model_name))
        mx = mjx.put_model(compiled_model)
        data0 = mjx.make_data(mx)
        hinges = [int(compiled_model.jnt_qposadr[j]) for j in range(compiled_model.njnt)
                  if compiled_model.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE]
        qpos = jnp.asarray(initial_qpos(compiled_model.qpos0, hinges, batch), jnp.float32)
        ctrl = controls(model_name)
        ctrl = data0.ctrl if ctrl is None else jnp.asarray(ctrl, data0.ctrl.dtype)
        data = jax.vmap(lambda q: data0.replace(qpos=q, ctrl=ctrl))(qpos)
        if batch == 1:
            data = jax.tree_util.tree_map(lambda a: a[0], data)
            advance = lambda d, m: mjx.step(m, d)
        else:
            advance = jax.vmap(lambda d, m: mjx.step(m, d), in_axes=(0, None))
        contact = "contact off" if compiled_model.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_CONTACT \
            else "contact on"
        row = PeerRow(model_name, "mjx", f"Euler, dt {compiled_model.opt.timestep:g} s, {contact}",
                      float(compiled_model.opt.timestep), batch, num_bodies(model_name), steps, None, 0.0,
                      {"width": width, "engine_bodies": compiled_model.nbody - 1})
        return _compiled_program(row, _loop(advance, steps), data, mx,
                                 lambda out: np.asarray(out.qpos, np.float64).reshape(batch, -1))


def brax_program(engine: str, mods: dict, model_name: str, batch: int, steps: int, width: str) -> _Program:
    """Brax's ``fori_loop`` over ``vmap(pipeline.step)`` with the ``engine`` pipeline, system from the MJCF."""
    mjcf, pipeline = mods["mjcf"], mods["pipeline"]
    with x64(False), warnings.catch_warnings():
        warnings.simplefilter("ignore")  # Brax warns that it is unmaintained on every load
        system = mjcf.loads(peer_mjcf(model_name))
        qpos0, hinges = _mujoco_layout(model_name)
        if system.q_size() != qpos0.shape[0]:
            raise ValueError(f"Brax's q has {system.q_size()} coordinates, MuJoCo's {qpos0.shape[0]}")
        qpos = jnp.asarray(initial_qpos(qpos0, hinges, batch), jnp.float32)
        zero_qd = jnp.zeros(system.qd_size(), jnp.float32)
        states = jax.jit(jax.vmap(lambda q: pipeline.init(system, q, zero_qd)))(qpos)
        ctrl = controls(model_name)
        act = jnp.zeros(system.act_size(), jnp.float32) if ctrl is None else jnp.asarray(ctrl)
        one = lambda s, sys_: pipeline.step(sys_, s, act)
        if batch == 1:
            states = jax.tree_util.tree_map(lambda a: a[0], states)
            advance = one
        else:
            advance = jax.vmap(one, in_axes=(0, None))
        row = PeerRow(model_name, engine, f"Euler, dt {float(system.opt.timestep):g} s, system from MJCF",
                      float(system.opt.timestep), batch, num_bodies(model_name), steps, None, 0.0,
                      {"width": width, "engine_bodies": int(system.num_links())})
        return _compiled_program(row, _loop(advance, steps), states, system,
                                 lambda out: np.asarray(out.q, np.float64).reshape(batch, -1))


def load_engines(engines: Sequence[str]) -> Tuple[Dict[str, dict], Dict[str, str]]:
    """Import the peers among ``engines`` (jaxrb needs nothing); return ``(modules, skipped)``.

    MJX, Brax positional and Brax spring through :func:`benchmarks.peer_runs.load_peers`;
    Brax generalized, which that does not know, the same way here.
    """
    unknown = [e for e in engines if e not in ENGINES]
    if unknown:
        raise ValueError(f"joints_engines: unknown {unknown}; valid: {', '.join(ENGINES)}")
    known = [e for e in engines if e in ("mjx", "brax_positional", "brax_spring")]
    modules, skipped = peer_runs.load_peers(known)
    if "brax_generalized" in engines:
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                from brax.generalized import pipeline
                from brax.io import mjcf
            modules["brax_generalized"] = {"mjcf": mjcf, "pipeline": pipeline}
        except Exception as error:  # an absent or broken peer is a note, not a failure
            skipped["brax_generalized"] = f"not importable: {type(error).__name__}: {error}"
    return modules, skipped


def _group_engines(model_name: str, settings: dict) -> Tuple[str, ...]:
    engines = settings["joints_floor_engines"] if model_name == "ant_floor" else settings["joints_engines"]
    if model_name == "chain":  # MJX's chain is probed apart (module docstring)
        engines = [e for e in engines if e != "mjx"]
    return tuple(engines)


#: The probe's child: compile one mjx.step of an n-link chain, print the compile time, then time calls.
_PROBE_CODE = """\
import sys, time
import jax
import mujoco
from mujoco import mjx
from benchmarks.joints_speed import chain_mjcf
compiled = mujoco.MjModel.from_xml_string(chain_mjcf(int(sys.argv[1])))
model = mjx.put_model(compiled)
data = mjx.make_data(model)
start = time.perf_counter()
step = jax.jit(mjx.step).lower(model, data).compile()
print("compile", time.perf_counter() - start, flush=True)
for _ in range(2):
    start = time.perf_counter()
    data = jax.block_until_ready(step(model, data))
    print("run", time.perf_counter() - start, flush=True)
"""


def mjx_chain_probe(links: Sequence[int], cap_s: float, log) -> List[PeerRow]:
    """One compiled ``mjx.step`` of an n-link chain at one world, for each n of ``links`` (increasing).

    Each length runs in a process of its own (the peers' ``XLA_FLAGS``, float32),
    ended ``cap_s`` seconds after its compile; its time per step is the faster
    of two calls, or, where no call ended in time, ``cap_s`` as a lower bound
    (``metrics["lower_bound"]``). Longer lengths are not tried after one runs out.

    Returns:
        Rows ``scene="chain"``, ``engine="mjx"``, ``batch=1``, ``num_steps=1``;
        ``metrics["links"]`` the length.
    """
    flags = peers.peer_process_flags()
    flags = os.environ.get("XLA_FLAGS", "") if flags is None else flags
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    rows = []
    for n in links:
        process = subprocess.Popen([sys.executable, "-c", _PROBE_CODE, str(n)], stdout=subprocess.PIPE,
                                   stderr=subprocess.DEVNULL, text=True,
                                   env=dict(os.environ, XLA_FLAGS=flags, JAX_ENABLE_X64="0", PYTHONPATH=root))
        compile_s, runs, timer = None, [], None
        try:
            for line in process.stdout:
                kind, _, value = line.strip().partition(" ")
                if kind not in ("compile", "run"):  # an engine's own message
                    continue
                if kind == "compile":  # the calls have cap_s from here: a process still calling is ended
                    compile_s = float(value)
                    timer = threading.Timer(cap_s, process.kill)
                    timer.start()
                else:
                    runs.append(float(value))
        finally:
            if timer is not None:
                timer.cancel()
            process.kill()
            process.wait()
        if compile_s is None:
            log(f"joints mjx chain probe {n} links: no compile (exit {process.returncode})")
            break
        bound = len(runs) == 0
        run_s = min(runs) if runs else cap_s
        rows.append(PeerRow("chain", "mjx", f"Euler, dt {CHAIN_DT:g} s, contact off, {n} links",
                            CHAIN_DT, 1, n, 1, compile_s, run_s,
                            {"width": width_name(), "links": n, "lower_bound": bound, "finite": True,
                             "first_hinge": math.nan}))
        log(f"joints {width_name()} mjx chain probe {n} links: compile {compile_s:.2f} s, one step "
            f"{'> ' if bound else ''}{run_s:.3g} s")
        if bound:
            break
    return rows


def _compile_into(programs: List[_Program], skipped: Dict[str, str], label: str, build: Callable[[], _Program],
                  model_name: str, batch: int, width: str, log) -> None:
    """``build()`` appended to ``programs``; a failure is a note in ``skipped`` under ``"label (model)"``."""
    try:
        program = build()
    except Exception as error:  # an engine that cannot run this model is a note, not a failure
        skipped[f"{label} ({model_name})"] = f"failed: {type(error).__name__}: {str(error)[:300]}"
        log(f"joints {model_name} {label} batch {batch}: FAILED {type(error).__name__}: {error}")
        return
    log(f"joints {width} {model_name:>9} {label:>16} batch {batch:>5}: compiled in {program.row.compile_s:.2f} s")
    programs.append(program)


def prepare_peers(model_name: str, batch: int, steps: int, engines: Sequence[str], modules: dict,
                  width: str, log) -> Tuple[List[_Program], Dict[str, str]]:
    """Compile every available peer of ``engines`` for one group; a failure is a note in ``skipped``."""
    programs, skipped = [], {}
    for engine in engines:
        if engine == "jaxrb" or engine not in modules:
            continue
        if engine == "mjx":
            build = lambda: mjx_program(modules[engine], model_name, batch, steps, width)
        else:
            build = lambda: brax_program(engine, modules[engine], model_name, batch, steps, width)
        _compile_into(programs, skipped, ENGINE_NAMES[engine], build, model_name, batch, width, log)
    return programs, skipped


def prepare_jaxrb(model_name: str, batch: int, steps: int, settings: dict, width: str,
                  log) -> Tuple[List[_Program], Dict[str, str]]:
    """Compile jaxrb's programs (one per integrator) for one group."""
    programs, skipped = [], {}
    if "jaxrb" not in _group_engines(model_name, settings):
        return programs, skipped
    for integrator in settings["joints_integrators"]:
        _compile_into(programs, skipped, f"jaxrb {integrator}",
                      lambda: jaxrb_program(model_name, integrator, batch, steps, width),
                      model_name, batch, width, log)
    return programs, skipped


# --- timing: programs called in turn, across this process and the peers' ---------------------

class _LocalSession:
    """Programs compiled in this process."""

    def __init__(self, programs: List[_Program], log=None):
        self.programs = programs
        self.log = log or (lambda text: None)

    def warm(self) -> None:
        for program in self.programs:
            self._announce(program)
            program.output = jax.block_until_ready(program.call())

    def _announce(self, program: _Program) -> None:
        self.log(f"joints calling {ENGINE_NAMES[program.row.engine]} ({program.row.scene}, "
                 f"{program.row.batch} worlds)")

    def round(self) -> float:
        """One timed call of every program, in order; returns the seconds spent."""
        spent = 0.0
        for program in self.programs:
            self._announce(program)
            start = time.perf_counter()
            program.output = jax.block_until_ready(program.call())
            elapsed = time.perf_counter() - start
            program.runs.append(elapsed)
            spent += elapsed
        return spent

    def finish(self) -> List[PeerRow]:
        """The rows, run_s the median of the timed calls, with the final state's figures."""
        rows = []
        for program in self.programs:
            row = program.row
            row.run_s = statistics.median(program.runs) if program.runs else math.nan
            row.metrics["runs_s"] = tuple(program.runs)
            row.metrics.update(_final_metrics(row.scene, program.read(program.output)))
            rows.append(row)
        self.programs = []
        return rows


def _final_metrics(model_name: str, qpos: np.ndarray) -> dict:
    """Figures of the final coordinates (batch, nq): all finite, and the first hinge's angle (mean over worlds)."""
    first_hinge = 0 if model_name == "chain" else 7  # the ant's free joint holds qpos[0:7]
    return {"finite": bool(np.all(np.isfinite(qpos))), "first_hinge": float(np.mean(qpos[:, first_hinge]))}


#: The child's loop: commands on stdin, one reply line each on the descriptor that was stdout.
_CHILD_CODE = """\
import os, pickle, sys
reply = os.fdopen(os.dup(1), "w")
os.dup2(2, 1)  # whatever the engines print goes to stderr
from benchmarks import joints_speed
joints_speed._serve(pickle.load(open(sys.argv[1], "rb")), sys.stdin, reply)
"""


def _serve(settings: dict, commands, reply) -> None:
    """The peers' process (:class:`_ChildSession`): ``prepare PATH``, ``warm``, ``round``, ``finish PATH``, ``quit``."""
    log = lambda text: print(text, file=sys.stderr, flush=True)
    engines = tuple(dict.fromkeys(e for key in ("joints_engines", "joints_floor_engines")
                                  for e in settings[key] if e != "jaxrb"))
    modules, skipped = load_engines(engines)
    session = _LocalSession([])
    for line in commands:
        command, _, argument = line.strip().partition(" ")
        answer = "ok"
        if command == "prepare":
            with open(argument, "rb") as handle:
                model_name, batch, steps, group_engines = pickle.load(handle)
            programs, why = prepare_peers(model_name, batch, steps, group_engines, modules,
                                          settings["_width"], log)
            session = _LocalSession(programs, log)
            with open(argument, "wb") as handle:
                pickle.dump({**{e: skipped[e] for e in group_engines if e in skipped}, **why}, handle)
            answer = f"ok {len(programs)}"
        elif command == "warm":
            session.warm()
        elif command == "round":
            answer = f"ok {session.round()!r}"
        elif command == "finish":
            with open(argument, "wb") as handle:
                pickle.dump(session.finish(), handle)
        elif command == "quit":
            reply.write("ok\n")
            reply.flush()
            return
        reply.write(answer + "\n")
        reply.flush()


class _ChildSession:
    """The peers' programs in a child process whose ``XLA_FLAGS`` are ``flags``, driven command by command.

    Every command waits for the child's reply, so one process runs while the
    other waits: compile times and timed calls never overlap.
    """

    def __init__(self, settings: dict, flags: str):
        self.folder = tempfile.TemporaryDirectory()
        path = os.path.join(self.folder.name, "settings.pickle")
        with open(path, "wb") as handle:
            pickle.dump(settings, handle)
        root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
        path_list = os.pathsep.join([root] + ([os.environ["PYTHONPATH"]] if os.environ.get("PYTHONPATH") else []))
        self.process = subprocess.Popen([sys.executable, "-c", _CHILD_CODE, path], stdin=subprocess.PIPE,
                                        stdout=subprocess.PIPE, stderr=None, text=True,
                                        env=dict(os.environ, XLA_FLAGS=flags, PYTHONPATH=path_list))
        self.count = 0
        self.timeout_s = settings["joints_peer_timeout_s"]

    def _ask(self, command: str) -> str:
        self.process.stdin.write(command + "\n")
        self.process.stdin.flush()
        # A peer's program that never returns (one hung idle in XLA's runtime here) ends the child.
        if not select.select([self.process.stdout], [], [], self.timeout_s)[0]:
            self.process.kill()
            raise RuntimeError(f"the peers' process gave no answer to {command.split()[0]!r} in "
                               f"{self.timeout_s:g} s and was ended")
        answer = self.process.stdout.readline()
        if not answer.startswith("ok"):
            raise RuntimeError(f"the peers' process did not answer {command.split()[0]!r} "
                               f"(exit status {self.process.poll()})")
        return answer[2:].strip()

    def prepare(self, model_name: str, batch: int, steps: int, engines: Sequence[str]) -> Dict[str, str]:
        path = os.path.join(self.folder.name, "group.pickle")
        with open(path, "wb") as handle:
            pickle.dump((model_name, batch, steps, tuple(engines)), handle)
        self.count = int(self._ask(f"prepare {path}"))
        with open(path, "rb") as handle:
            return pickle.load(handle)

    def warm(self) -> None:
        self._ask("warm")

    def round(self) -> float:
        return float(self._ask("round"))

    def finish(self) -> List[PeerRow]:
        path = os.path.join(self.folder.name, "rows.pickle")
        self._ask(f"finish {path}")
        with open(path, "rb") as handle:
            return pickle.load(handle)

    def close(self) -> None:
        try:
            if self.process.poll() is None:
                self._ask("quit")
            self.process.wait(timeout=60)
        except Exception:  # a child that hangs on the way out is ended; its rows are already read
            self.process.kill()
            self.process.wait()
        finally:
            self.folder.cleanup()


def width_name() -> str:
    """This process's width: ``"avx2"`` where ``XLA_FLAGS`` caps the ISA at AVX2, else ``"native"``."""
    return "avx2" if WIDTHS["avx2"] in os.environ.get("XLA_FLAGS", "") else "native"


def _groups(settings: dict) -> List[Tuple[str, int, int]]:
    groups = []
    for model_name in settings["joints_models"]:
        if model_name not in MODELS:
            raise ValueError(f"joints_models: unknown {model_name!r}; valid: {', '.join(MODELS)}")
        pairs = settings["joints_floor_batches"] if model_name == "ant_floor" else settings["joints_batches"]
        groups += [(model_name, int(batch), int(steps)) for batch, steps in pairs]
    return groups


def run_width(settings: dict, log=None) -> Tuple[List[PeerRow], Dict[str, str]]:
    """Every group (model, batch) at this process's width: jaxrb here, the peers here or in a child.

    Returns:
        ``(rows, skipped)``.
    """
    settings = {**FULL, **settings}
    log = log or (lambda text: None)
    width = width_name()
    settings["_width"] = width
    peer_engines = tuple(dict.fromkeys(e for key in ("joints_engines", "joints_floor_engines")
                                       for e in settings[key] if e != "jaxrb"))
    modules, skipped = {}, {}
    child_flags = peers.peer_process_flags()
    child = None
    if peer_engines and child_flags is None:
        modules, skipped = load_engines(peer_engines)
    rows: List[PeerRow] = []
    try:
        for model_name, batch, steps in _groups(settings):
            engines = _group_engines(model_name, settings)
            programs, why = prepare_jaxrb(model_name, batch, steps, settings, width, log)
            skipped.update(why)
            if child_flags is not None and peer_engines:
                child = child or _ChildSession(settings, child_flags)
                try:
                    skipped.update(child.prepare(model_name, batch, steps, engines))
                    remote = child if child.count else None
                except RuntimeError as error:
                    skipped[f"peers ({model_name}, {batch} worlds)"] = f"failed: {error}"
                    child.close()
                    child, remote = None, None
            else:
                theirs, why = prepare_peers(model_name, batch, steps, engines, modules, width, log)
                skipped.update(why)
                programs += theirs
                remote = None
            sessions = [_LocalSession(programs, log)] + ([remote] if remote is not None else [])
            try:
                for session in sessions:
                    session.warm()
                spent = 0.0
                for index in range(max(1, settings["joints_repeats"])):
                    spent += sum(session.round() for session in sessions)
                    if spent > settings["joints_budget_s"] and index + 1 >= settings["joints_min_repeats"]:
                        break
                group_rows = [row for session in sessions for row in session.finish()]
            except RuntimeError as error:  # the peers' process hung: this group's jaxrb rows alone, a new child next
                skipped[f"peers ({model_name}, {batch} worlds)"] = f"failed: {error}"
                child.close()
                child = None
                sessions[0].warm()
                sessions[0].round()
                group_rows = sessions[0].finish()
            for row in group_rows:
                log(f"joints {width} {model_name:>9} {ENGINE_NAMES[row.engine]:>16} batch {batch:>5}: "
                    f"{row.setting}: compile {row.compile_s:.2f} s, run {row.run_s:.4f} s "
                    f"({len(row.metrics['runs_s'])} rounds), {fmt_si(row.body_steps_per_s, ' body-steps/s')}")
            rows += group_rows
    finally:
        if child is not None:
            child.close()
    if "chain" in settings["joints_models"] and "mjx" in settings["joints_engines"]:
        rows += mjx_chain_probe(settings["joints_mjx_chain_links"], settings["joints_mjx_cap_s"], log)
    return rows, skipped


def _run_width_in_child(settings: dict, width: str) -> Tuple[List[PeerRow], Dict[str, str]]:
    """:func:`run_width` in a new interpreter whose ``XLA_FLAGS`` add :data:`WIDTHS` ``[width]``."""
    with tempfile.TemporaryDirectory() as folder:
        path = os.path.join(folder, "joints.pickle")
        with open(path, "wb") as handle:
            pickle.dump(settings, handle)
        code = ("import pickle, sys\n"
                "from benchmarks import joints_speed\n"
                "settings = pickle.load(open(sys.argv[1], 'rb'))\n"
                "log = lambda text: print(text, file=sys.stderr, flush=True)\n"
                "result = joints_speed.run_width(settings, log)\n"
                "pickle.dump(result, open(sys.argv[1], 'wb'))\n")
        root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
        path_list = os.pathsep.join([root] + ([os.environ["PYTHONPATH"]] if os.environ.get("PYTHONPATH") else []))
        flags = " ".join([os.environ.get("XLA_FLAGS", ""), WIDTHS[width]]).strip()
        done = subprocess.run([sys.executable, "-c", code, path],
                              env=dict(os.environ, XLA_FLAGS=flags, PYTHONPATH=path_list),
                              stdout=subprocess.DEVNULL, stderr=None)
        if done.returncode != 0:
            return [], {f"width {width}": f"failed: its process exited with {done.returncode}"}
        with open(path, "rb") as handle:
            return pickle.load(handle)


def run_joints(settings: dict, log=None) -> Tuple[List[PeerRow], Dict[str, str]]:
    """Every width of ``joints_widths``: the native one here, the others in a child interpreter each."""
    settings = {**FULL, **settings}
    rows, skipped = [], {}
    for width in settings["joints_widths"]:
        if width not in WIDTHS:
            raise ValueError(f"joints_widths: unknown {width!r}; valid: {', '.join(WIDTHS)}")
        if WIDTHS[width] is None and width_name() == "native":
            mine, why = run_width(settings, log)
        else:
            mine, why = _run_width_in_child(settings, width)
        rows += mine
        skipped.update({f"{k} [{width}]": v for k, v in why.items()})
    return rows, skipped


# --- the report -----------------------------------------------------------------------------

def _label(row: PeerRow) -> str:
    if row.engine == "jaxrb":
        return f"jaxrb {row.metrics['integrator']}"
    return ENGINE_NAMES[row.engine]


def model_table(model_name: str, rows: Sequence[PeerRow]) -> str:
    """One model's table: every engine at every width and batch, and jaxrb's ratios over each row."""
    mine = [r for r in rows if r.scene == model_name and "links" not in r.metrics]  # not the MJX probe
    widths = [w for w in WIDTHS if any(r.metrics["width"] == w for r in mine)]
    integrators = list(dict.fromkeys(r.metrics["integrator"] for r in mine if r.engine == "jaxrb"))
    headers = (["width", "worlds", "engine", "setting", "bodies", "steps", "compile (s)", "run (s)",
                "body-steps/s", "sim s/s", "body-s/s"]
               + [f"jaxrb {name} / this" for name in integrators] + ["first hinge at end (rad)"])
    table_rows = []
    for width in widths:
        for batch in sorted({r.batch for r in mine if r.metrics["width"] == width}):
            group = [r for r in mine if r.metrics["width"] == width and r.batch == batch]
            group.sort(key=lambda r: (ENGINES.index(r.engine), r.metrics.get("integrator", "")))
            jaxrb_rows = {r.metrics["integrator"]: r for r in group if r.engine == "jaxrb"}
            for row in group:
                bodies = str(row.num_bodies)
                if row.metrics.get("engine_bodies", row.num_bodies) != row.num_bodies:
                    bodies += f" ({row.metrics['engine_bodies']} links)"
                sim_rate = row.batch * row.num_steps * row.h / row.run_s if row.run_s > 0 else math.nan
                hinge = fmt_fixed(row.metrics["first_hinge"], 4) + ("" if row.metrics["finite"] else ", NOT finite")
                table_rows.append(
                    [width, row.batch, _label(row), row.setting, bodies, row.num_steps, fmt_fixed(row.compile_s, 2),
                     fmt_fixed(row.run_s, 4), fmt_si(row.body_steps_per_s), fmt_si(sim_rate),
                     fmt_si(row.body_steps_per_s * row.h)]
                    + [fmt_fixed(ratio(jaxrb_rows[name].body_steps_per_s, row.body_steps_per_s), 2) + "×"
                       if name in jaxrb_rows else "—" for name in integrators]
                    + [hinge])
    return markdown_table(headers, table_rows, align=["l", "r", "l", "l"] + ["r"] * (len(headers) - 4))


def probe_table(rows: Sequence[PeerRow]) -> str:
    """MJX's chain probe: one step at one world for each chain length and width."""
    probes = [r for r in rows if "links" in r.metrics]
    if not probes:
        return ""
    table_rows = [[r.metrics["width"], r.metrics["links"], fmt_fixed(r.compile_s, 2),
                   ("> " if r.metrics["lower_bound"] else "") + fmt_fixed(r.run_s, 3)] for r in probes]
    return markdown_table(["width", "links", "compile (s)", "one step (s)"], table_rows,
                          align=["l", "r", "r", "r"])


def width_table(rows: Sequence[PeerRow]) -> str:
    """Native over AVX2 body-steps/s of every engine at every model and batch (both widths present)."""
    rows = [r for r in rows if "links" not in r.metrics]
    native = {(r.scene, r.batch, _label(r)): r for r in rows if r.metrics["width"] == "native"}
    pairs = [(key, native[key], r) for r in rows if r.metrics["width"] == "avx2"
             for key in [(r.scene, r.batch, _label(r))] if key in native]
    if not pairs:
        return ""
    table_rows = [[key[0], key[1], key[2], fmt_si(a.body_steps_per_s), fmt_si(b.body_steps_per_s),
                   fmt_fixed(ratio(a.body_steps_per_s, b.body_steps_per_s), 2) + "×"] for key, a, b in pairs]
    return markdown_table(["model", "worlds", "engine", "native body-steps/s", "AVX2 body-steps/s",
                           "native / AVX2"], table_rows, align=["l", "r", "l", "r", "r", "r"])


@dataclasses.dataclass
class Target:
    """One of the issue's speed targets at one model, batch, width and jaxrb integrator."""

    what: str
    measured: str
    met: Optional[bool]


def evaluate_targets(rows: Sequence[PeerRow]) -> List[Target]:
    """The issue's targets: for each air model, width, batch and integrator, jaxrb ahead of every Brax
    pipeline that ran and ≥ 10× MJX (body-steps/s, hence body-s/s at the same dt), and compile ≤ 5 s."""
    targets = []
    for model_name in ("chain", "ant_air"):
        for width in WIDTHS:
            for batch in sorted({r.batch for r in rows if r.scene == model_name and r.metrics["width"] == width}):
                group = [r for r in rows if r.scene == model_name and r.metrics["width"] == width
                         and r.batch == batch and r.metrics.get("links", CHAIN_LINKS) == CHAIN_LINKS]
                for mine in [r for r in group if r.engine == "jaxrb"]:
                    where = f"{model_name}, {width}, {batch} world{'s' if batch > 1 else ''}, " \
                            f"jaxrb {mine.metrics['integrator']}"
                    brax = [r for r in group if r.engine in BRAX_ENGINES]
                    if brax:
                        best = max(brax, key=lambda r: r.body_steps_per_s)
                        value = ratio(mine.body_steps_per_s, best.body_steps_per_s)
                        targets.append(Target(f"{where}: ahead of every Brax pipeline",
                                              f"{value:.2f}× the fastest ({ENGINE_NAMES[best.engine]})",
                                              value > 1.0))
                    for mjx_row in [r for r in group if r.engine == "mjx"]:
                        value = ratio(mine.body_steps_per_s, mjx_row.body_steps_per_s)
                        bound = mjx_row.metrics.get("lower_bound", False)  # MJX ran out of time: at least this
                        targets.append(Target(f"{where}: ≥ {MJX_FACTOR:g}× MJX",
                                              f"{'> ' if bound else ''}{value:.3g}×", value >= MJX_FACTOR))
    compiles = [r for r in rows if r.engine == "jaxrb" and r.compile_s is not None]
    if compiles:
        worst = max(compiles, key=lambda r: r.compile_s)
        targets.append(Target(f"jaxrb compile ≤ {COMPILE_TARGET_S:g} s (every jaxrb program)",
                              f"longest {worst.compile_s:.2f} s ({worst.scene}, {worst.metrics['width']}, "
                              f"{worst.batch} worlds, {worst.metrics['integrator']})",
                              worst.compile_s <= COMPILE_TARGET_S))
    return targets


def targets_table(targets: Sequence[Target]) -> str:
    return markdown_table(["target", "measured", "met"],
                          [[t.what, t.measured, "—" if t.met is None else ("yes" if t.met else "**no**")]
                           for t in targets], align=["l", "r", "l"])


def hardware_line() -> str:
    """The host's processor, cores and whether it lists AVX-512F."""
    cpu = cpuinfo()
    flags = cpu.get("flags", "").split()
    return (f"{cpu.get('model name', '?')}, {os.cpu_count()} cores, avx512f "
            f"{'present' if 'avx512f' in flags else 'absent'}, avx2 {'present' if 'avx2' in flags else 'absent'}")


def markdown(rows: Sequence[PeerRow], skipped: Dict[str, str], settings: dict) -> str:
    """The section's Markdown from its results."""
    settings = {**FULL, **settings}
    parts = [
        f"Host: {hardware_line()}. Every engine in float32 at the same dt (0.01 s) for the same steps, "
        "from the same start (MuJoCo's qpos0; a batch's worlds differ by hinge angles in ±0.01 rad); the ant's "
        f"motors hold the controls {ANT_CONTROLS}. Each program is a `fori_loop` over the engine's step "
        "(vmapped over the worlds at a batch > 1); *compile* = trace + lower + compile; *run* = median "
        "wall time of one call, the programs of a model and batch called in turn, round by round, "
        "across this process and the peers' (which runs without jaxrb's LLVM unroll limit, as in the peers "
        "section). body-steps/s = worlds · bodies · steps / run; sim s/s = simulated seconds of all "
        "worlds per wall second; body-s/s = body-steps/s · dt. Ratios are jaxrb's body-steps/s over the "
        "row's, at the same width and batch (the same as their sim s/s ratios: same dt, same body count). "
        "*native* is the host's full width (AVX-512 listed; XLA still prefers 256-bit vectors), *avx2* the "
        "same run with `--xla_cpu_max_isa=AVX2` appended to XLA_FLAGS, in a process of its own. MJX and "
        "Brax read the ant with integrator Euler (Brax does not load the file's RK4: \"Only euler "
        "integration is supported\"); in the air with `<flag contact=\"disable\"/>`. *first hinge at "
        "end*: the first hinge's angle after the run, mean over worlds (the chain's root hinge, the ant's "
        "hip_4): engines that simulate the same motion agree.",
    ]
    for model_name in MODELS:
        if any(r.scene == model_name for r in rows):
            parts += [f"**{MODEL_TITLES[model_name]}**", "", model_table(model_name, rows)]
    probes = probe_table(rows)
    if probes:
        parts += ["**MJX on the chain**: one compiled `mjx.step` at one world, each chain length in a process "
                  f"of its own ended {settings['joints_mjx_cap_s']:g} s after compiling (\">\": no step ended "
                  "in time, a lower bound). Its time grows about 20-fold a link past 8, so the chain's timed "
                  "groups leave MJX out and its target is judged on the 10-link row at one world.", "", probes]
    widths = width_table(rows)
    if widths:
        parts += ["**Width**: native body-steps/s over AVX2's, engine by engine.", "", widths]
    targets = evaluate_targets(rows)
    if targets:
        parts += ["**Targets** of the issue \"Joints\" (air models; ratios of body-steps/s):", "",
                  targets_table(targets)]
    if skipped:
        missing = any(v.startswith("not importable") for v in skipped.values())
        parts += ["**Skipped**: " + "; ".join(f"{ENGINE_NAMES.get(k, k)}: {v}" for k, v in skipped.items())
                  + (". Install the peers with `pip install -e \".[peers]\"`." if missing else ".")]
    left_out = [MODEL_TITLES[m] for m in MODELS if m not in settings["joints_models"]]
    left_out += [ENGINE_NAMES[e] for e in ENGINES if e not in settings["joints_engines"]]
    left_out += [f"width {w}" for w in WIDTHS if w not in settings["joints_widths"]]
    if left_out:
        parts.append(f"**Not run with these settings**: {', '.join(left_out)} (the full run has them).")
    return "\n\n".join(p for p in parts if p != "").replace("\n\n\n", "\n\n")


def joints_speed_section(settings: Optional[dict] = None, log=None):
    """Run the joints speed benchmark; return ``(markdown, results)`` like the other sections.

    Args:
        settings: :data:`QUICK`, :data:`FULL` or any subset of their keys (the
            rest from :data:`FULL`); other keys are ignored.
        log: optional ``log(text)`` for progress lines.

    Returns:
        ``(markdown, results)`` with ``results`` a dict: ``rows`` (list of
        :class:`~benchmarks.scenes.PeerRow`; ``metrics`` hold ``width``,
        ``integrator`` for jaxrb, ``runs_s``, ``finite``, ``first_hinge``),
        ``skipped`` (dict of reasons) and ``targets`` (list of :class:`Target`).
    """
    settings = {**FULL, **{k: v for k, v in (settings or {}).items() if k.startswith("joints_")}}
    rows, skipped = run_joints(settings, log)
    return markdown(rows, skipped, settings), {"rows": rows, "skipped": skipped,
                                               "targets": evaluate_targets(rows)}


def main(argv=None) -> int:
    """``python -m benchmarks.joints_speed [--quick] [--out FILE]``: the section's Markdown to stdout (and FILE)."""
    import argparse

    parser = argparse.ArgumentParser(prog="python -m benchmarks.joints_speed", description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="the chain at 1 and 8 worlds, native width only")
    parser.add_argument("--out", default=None, metavar="FILE", help="also write the Markdown here")
    args = parser.parse_args(argv)
    log = lambda text: print(text, file=sys.stderr, flush=True)
    start = time.perf_counter()
    text, _ = joints_speed_section(QUICK if args.quick else FULL, log)
    text += f"\n\nSection wall time: {time.perf_counter() - start:.0f} s.\n"
    print(text)
    if args.out:
        with open(args.out, "w", encoding="utf-8") as handle:
            handle.write(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
