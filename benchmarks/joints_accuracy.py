"""Joints against MuJoCo, same file, side by side: how close each integrator stays to MuJoCo's RK4.

The models: gymnasium's ``inverted_pendulum``, ``inverted_double_pendulum``,
``hopper`` and ``ant`` (armature, damping, gears and gravity as their files
say), and a double pendulum of two 0.5 m capsules. From random states
(hinges and slides uniform within their ranges, quaternions turned by up to
about 0.3 rad, velocities N(0, 0.5²), controls uniform within ``ctrlrange``,
seeded) with contact off and, as the section says, limits off (jaxrb's limits
are stiffer than MuJoCo's soft ones by design, so with limits on the two
differ once a joint reaches one), each engine steps at h = 1e-4 s for 0.1 s
(the double pendulum from (2.0, −1.0) rad for 1 s) and the distance in qpos
to MuJoCo's RK4 at the same step is taken at every 1 ms: millimetres for
slides and a free body's position, degrees for hinges and a ball's or free
body's rotation (the angle of the relative rotation). MuJoCo's own Euler is
the yardstick: jaxrb's default integrator should stay at least as close.
"""

from __future__ import annotations

import os
import time

import numpy as np

from jaxrb.bench.report import markdown_table

MODELS = ("inverted_pendulum", "inverted_double_pendulum", "hopper", "ant")
INTEGRATORS = ("midpoint", "semi_implicit", "rk4")
FULL = dict(models=MODELS + ("double_pendulum",), states=20, step=1e-4, seconds=0.1, pendulum_seconds=1.0)
QUICK = dict(models=MODELS + ("double_pendulum",), states=2, step=1e-3, seconds=0.05, pendulum_seconds=0.2)

DOUBLE_PENDULUM_XML = """
<mujoco model="double_pendulum"><option gravity="0 0 -9.81"/><worldbody>
  <body><joint type="hinge" axis="0 1 0"/><geom type="capsule" fromto="0 0 0 0 0 -0.5" size="0.02" mass="1"/>
    <body pos="0 0 -0.5"><joint type="hinge" axis="0 1 0"/>
      <geom type="capsule" fromto="0 0 0 0 0 -0.5" size="0.02" mass="1"/></body></body>
</worldbody></mujoco>"""

_FREE, _BALL, _SLIDE, _HINGE = 0, 1, 2, 3


def _quat_multiply(a, b):
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2])


def random_states(model, count, seed):
    """``count`` seeded states (qpos (count, nq), qvel (count, nv), ctrl (count, nu)) of an MjModel (module docs)."""
    rng = np.random.default_rng(seed)
    qpos = np.tile(model.qpos0, (count, 1))
    for j in range(model.njnt):
        kind, start = int(model.jnt_type[j]), int(model.jnt_qposadr[j])
        if kind in (_HINGE, _SLIDE):
            low, high = model.jnt_range[j] if model.jnt_limited[j] else \
                (model.qpos0[start] + np.array([-1.0, 1.0]) * (1.0 if kind == _HINGE else 0.1))
            qpos[:, start] = rng.uniform(low, high, size=count)
            continue
        start += 3 if kind == _FREE else 0
        for k in range(count):
            turn = rng.normal(0.0, 0.3, size=3)
            angle = np.linalg.norm(turn)
            small = np.concatenate([[np.cos(angle / 2)], np.sin(angle / 2) * turn / max(angle, 1e-12)])
            quat = _quat_multiply(model.qpos0[start:start + 4], small)
            qpos[k, start:start + 4] = quat / np.linalg.norm(quat)
    qvel = rng.normal(0.0, 0.5, size=(count, model.nv))
    ranges = np.where(model.actuator_ctrllimited[:, None], model.actuator_ctrlrange, [-1.0, 1.0])
    ctrl = rng.uniform(ranges[:, 0], ranges[:, 1], size=(count, model.nu))
    return qpos, qvel, ctrl


def distances(model, first, second):
    """(mm, degrees): the largest distance between two qpos trajectories (T, nq), split by kind."""
    linear, angular = [0.0], [0.0]
    for j in range(model.njnt):
        kind, start = int(model.jnt_type[j]), int(model.jnt_qposadr[j])
        if kind == _SLIDE:
            linear.append(1e3 * np.abs(first[:, start] - second[:, start]).max())
        elif kind == _HINGE:
            angular.append(np.degrees(np.abs(first[:, start] - second[:, start]).max()))
        else:
            if kind == _FREE:
                linear.append(1e3 * np.linalg.norm(first[:, start:start + 3] - second[:, start:start + 3], axis=-1).max())
                start += 3
            a, b = first[:, start:start + 4], second[:, start:start + 4]
            a = a / np.linalg.norm(a, axis=-1, keepdims=True)
            b = b / np.linalg.norm(b, axis=-1, keepdims=True)
            cosine = np.abs(np.sum(a * b, axis=-1))
            angular.append(np.degrees(2.0 * np.arccos(np.clip(cosine, 0.0, 1.0))).max())
    return max(linear), max(angular)


def mujoco_rollout(mujoco, model, qpos, qvel, ctrl, integrator, step, seconds, every):
    """MuJoCo's qpos every ``every`` steps (excluding the start) with contact and limits off."""
    model.opt.timestep = step
    model.opt.integrator = {"Euler": 0, "RK4": 1}[integrator]
    data = mujoco.MjData(model)
    data.qpos[:], data.qvel[:], data.ctrl[:] = qpos, qvel, ctrl
    saved = []
    for k in range(int(round(seconds / step))):
        mujoco.mj_step(model, data)
        if (k + 1) % every == 0:
            saved.append(data.qpos.copy())
    return np.asarray(saved)


def joints_accuracy_section(settings: dict, log=print):
    """Run the section; return ``(markdown, results)``."""
    import gymnasium
    import jax
    import jax.numpy as jnp
    import mujoco

    import jaxrb as rb
    from jaxrb.files.mjcf import scene_from_mjmodel

    assets = os.path.join(os.path.dirname(gymnasium.__file__), "envs", "mujoco", "assets")
    step = settings["step"]
    every = max(1, int(round(1e-3 / step)))
    rows, results = [], {}
    with jax.enable_x64(True):
        for name in settings["models"]:
            started = time.perf_counter()
            if name == "double_pendulum":
                model = mujoco.MjModel.from_xml_string(DOUBLE_PENDULUM_XML)
                qpos, qvel, ctrl = np.array([[2.0, -1.0]]), np.zeros((1, 2)), np.zeros((1, 0))
                seconds = settings["pendulum_seconds"]
            else:
                model = mujoco.MjModel.from_xml_path(os.path.join(assets, f"{name}.xml"))
                qpos, qvel, ctrl = random_states(model, settings["states"], seed=0)
                seconds = settings["seconds"]
            model.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONTACT) | int(mujoco.mjtDisableBit.mjDSBL_LIMIT)
            found = scene_from_mjmodel(model, name)
            steps = int(round(seconds / step))
            worst = {key: np.zeros(2) for key in INTEGRATORS + ("MuJoCo Euler",)}
            references = [mujoco_rollout(mujoco, model, *start, "RK4", step, seconds, every)
                          for start in zip(qpos, qvel, ctrl)]
            euler = [mujoco_rollout(mujoco, model, *start, "Euler", step, seconds, every)
                     for start in zip(qpos, qvel, ctrl)]
            for reference, theirs in zip(references, euler):
                worst["MuJoCo Euler"] = np.maximum(worst["MuJoCo Euler"], distances(model, theirs, reference))
            for integrator in INTEGRATORS:
                built, params, state = found.build(dt=step, integrator=integrator, contact="none", substeps=1,
                                                   dtype="float64")
                run = rb.jit(lambda q, v, u: rb.rollout(
                    rb.make_step(built), rb.joints.set_qpos_qvel(built, params, state, q, v), params, steps,
                    every=every, controls=jnp.broadcast_to(u, (steps, built.num_actuators))).qpos)
                batched = np.asarray(jax.vmap(run)(jnp.asarray(qpos), jnp.asarray(qvel), jnp.asarray(ctrl)))
                for ours, reference in zip(batched, references):
                    worst[integrator] = np.maximum(worst[integrator], distances(model, ours, reference))
            results[name] = {key: value.tolist() for key, value in worst.items()}
            cell = lambda value: f"{value[0]:.3g} mm, {value[1]:.3g}°"
            rows.append([name, f"{len(qpos)} × {seconds:g} s"] + [cell(worst[key]) for key in
                                                                ("MuJoCo Euler",) + INTEGRATORS])
            log(f"joints_accuracy: {name} in {time.perf_counter() - started:.0f} s")
    header = ["model", "states × time", "MuJoCo Euler", "jaxrb midpoint (default)", "jaxrb semi_implicit",
              "jaxrb rk4"]
    text = (f"Largest distance in qpos to MuJoCo's RK4 at the same step h = {step:g} s, sampled every "
            f"{every * step * 1e3:g} ms, contact and limits off, float64 (module docs of "
            "`benchmarks/joints_accuracy.py`). Target: jaxrb's default at least as close as MuJoCo's Euler; "
            "rk4 within 0.01 mm and 0.001°.\n\n" + markdown_table(header, rows))
    return text, results
