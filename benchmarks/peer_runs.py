"""The peers' runs of the scenes: MuJoCo C, MJX, Brax (spring and positional), Jax2D and pymunk.

:func:`load_peers` imports the engines asked for; one that is absent or
broken is a reason in ``skipped``, not an error. Each run builds the scene of
:mod:`benchmarks.scenes` in the peer's own terms (MJCF for MuJoCo, MJX and
Brax; Jax2D's and pymunk's scene APIs), steps it at the peer's step and
returns a :class:`~benchmarks.scenes.PeerRow` with the same figures as
jaxrb's rows (:mod:`benchmarks.jaxrb_runs`). The peers' JAX code runs with
x64 off, in float32 like jaxrb's throughput runs; MuJoCo C is float64 and is
timed with ``time.perf_counter`` around its calls from Python (one world) and
around ``mujoco.rollout`` (a loop over worlds in C, one thread).
"""

from __future__ import annotations

import statistics
import time
from typing import Callable, Dict, List, Sequence, Tuple

import jax
import jax.numpy as jnp
import numpy as np

from benchmarks.scenes import (ENGINES, FRICTION, HALF, PEER_STEP, PYRAMID_TOP, STACK_COUNT, STACK_TOP_REST, PeerRow,
                               drop_mjcf, free_qpos, pyramid_centres, rest_metrics, stack_mjcf, stack_metrics,
                               time_jax, tumbler_mjcf, world_shifts, x64)
from jaxrb.bench import free_body


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
                    run_s, rest_metrics([qpos[2]]))]
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
        initial[:, 1:1 + 7] = free_qpos(model.qpos0, 1, world_shifts(worlds, 3))  # state = (time, qpos, ...)
        run_s, (states, _) = _median_wall(
            lambda: rollout.rollout(model, data, initial, nstep=num_steps), settings["peers_repeats"])
        rows.append(PeerRow("drop", "mujoco", "Euler, mujoco.rollout (C loop, 1 thread)", PEER_STEP,
                            worlds, 1, num_steps, None, run_s, rest_metrics(states[:, -1, 1 + 2])))
    return rows


def mujoco_stack(mods: dict, seconds: float, settings: dict) -> PeerRow:
    """MuJoCo C 10-box column, one world, for ``seconds`` at h = 2 ms."""
    mujoco = mods["mujoco"]
    num_steps = max(1, int(round(seconds / PEER_STEP)))
    model, run_s, qpos = _mujoco_one_world(mujoco, stack_mjcf(), num_steps, settings["peers_repeats"])
    top = slice(7 * (STACK_COUNT - 1), 7 * (STACK_COUNT - 1) + 3)
    return PeerRow("stack", "mujoco", "Euler, mj_step from Python", PEER_STEP, 1, STACK_COUNT, num_steps,
                   None, run_s, stack_metrics(model.qpos0[top][None], qpos[top][None], STACK_TOP_REST))


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
        qpos = jnp.asarray(free_qpos(model.qpos0, num_bodies, world_shifts(batch, 3)), jnp.float32)
        data = jax.vmap(lambda q: data0.replace(qpos=q))(qpos)
        step = jax.vmap(mjx.step, in_axes=(None, 0))
        timing = time_jax(lambda d, m: _scan_final(lambda c, mm: step(mm, c), num_steps)(d, m),
                           data, mx, settings=settings)
        return timing, np.asarray(qpos, np.float64), np.asarray(timing.output.qpos, np.float64)


def mjx_drop(mods: dict, batch: int, num_steps: int, settings: dict) -> PeerRow:
    """MJX box drop: ``jax.vmap`` of ``mjx.step`` over a batch of ``mjx.Data``, scanned in one jit."""
    timing, _, final = _mjx_batched(mods, drop_mjcf(), 1, batch, num_steps, settings)
    return PeerRow("drop", "mjx", "Euler, vmap(mjx.step)", PEER_STEP, batch, 1, num_steps,
                   timing.compile_s, timing.run_s, rest_metrics(final[:, 2]))


def mjx_stack(mods: dict, batch: int, seconds: float, settings: dict) -> PeerRow:
    """MJX 10-box column at h = 2 ms, batched like :func:`mjx_drop`."""
    num_steps = max(1, int(round(seconds / PEER_STEP)))
    timing, initial, final = _mjx_batched(mods, stack_mjcf(), STACK_COUNT, batch, num_steps, settings)
    top = slice(7 * (STACK_COUNT - 1), 7 * (STACK_COUNT - 1) + 3)
    return PeerRow("stack", "mjx", "Euler, vmap(mjx.step)", PEER_STEP, batch, STACK_COUNT, num_steps,
                   timing.compile_s, timing.run_s, stack_metrics(initial[:, top], final[:, top], STACK_TOP_REST))


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

        timing = time_jax(trajectory, data, mx, settings=settings)
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
        qpos = jnp.asarray(free_qpos(np.asarray(system.init_q), num_bodies, world_shifts(batch, 3)),
                           jnp.float32)
        zero_qd = jnp.zeros(system.qd_size(), jnp.float32)
        states = jax.jit(jax.vmap(lambda q: pipeline.init(system, q, zero_qd)))(qpos)
        act = jnp.zeros(system.act_size(), jnp.float32)
        step = jax.vmap(lambda s, sys_: pipeline.step(sys_, s, act), in_axes=(0, None))
        timing = time_jax(_scan_final(step, num_steps), states, system, settings=settings)
        return timing, np.asarray(qpos, np.float64), np.asarray(timing.output.q, np.float64)


def brax_drop(engine: str, mods: dict, batch: int, num_steps: int, settings: dict) -> PeerRow:
    """Brax box drop with the spring or positional pipeline, system from :func:`drop_mjcf`."""
    timing, _, final = _brax_batched(mods, drop_mjcf(), 1, batch, num_steps, settings)
    return PeerRow("drop", engine, "vmap(pipeline.step), system from MJCF", PEER_STEP, batch, 1,
                   num_steps, timing.compile_s, timing.run_s, rest_metrics(final[:, 2]))


def brax_stack(engine: str, mods: dict, batch: int, seconds: float, settings: dict) -> PeerRow:
    """Brax 10-box column at h = 2 ms, batched like :func:`brax_drop`."""
    num_steps = max(1, int(round(seconds / PEER_STEP)))
    timing, initial, final = _brax_batched(mods, stack_mjcf(), STACK_COUNT, batch, num_steps, settings)
    top = slice(7 * (STACK_COUNT - 1), 7 * (STACK_COUNT - 1) + 3)
    return PeerRow("stack", engine, "vmap(pipeline.step), system from MJCF", PEER_STEP, batch,
                   STACK_COUNT, num_steps, timing.compile_s, timing.run_s,
                   stack_metrics(initial[:, top], final[:, top], STACK_TOP_REST))


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
        timing = time_jax(_scan_final(step, num_steps), batched, params, settings=settings)
        top = fixed + PYRAMID_TOP
        initial = np.asarray(batched.polygon.position[:, top], np.float64)
        final = np.asarray(timing.output.polygon.position[:, top], np.float64)
    return PeerRow("pyramid", "jax2d", "1/60 s, 10 iterations, vmap(engine.step)", float(params.dt),
                   batch, count, num_steps, timing.compile_s, timing.run_s,
                   stack_metrics(initial, final, pyramid_centres()[PYRAMID_TOP][1]))


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
                   stack_metrics(initial, np.array([runs[-1][1]]), initial[0, 1]))
