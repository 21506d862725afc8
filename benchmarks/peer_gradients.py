"""Gradients through contact side by side: jaxrb and the peers that differentiate (MJX, Brax).

The scene is the peers' box drop (:mod:`benchmarks.scenes`: a 0.2 m box,
1 kg, released from rest with its centre at 0.5 m above a plane, μ = 0.5),
every engine at h = 2 ms for T steps (T = 1 000: the fall, the landing at
about step 143, then rest), float32, in one world and, for jaxrb's penalty
adjoint and Brax spring (the one peer whose gradient is finite here), in a
batch of worlds that differ by the drop benchmark's tiny shifts
(:func:`benchmarks.scenes.world_shifts`), the loss their mean. Each engine
differentiates the same loss of the motion, the mean over the T steps of the squares of the
position, the linear and angular velocity and the quaternion's vector part
(:func:`jaxrb.bench.gradients.trajectory_loss`; a mean of squares of the
angular velocity's components is the same in the world and the body frame,
so a peer's generalised velocity gives the same number):

* **jaxrb**, with respect to every field of Params and the initial motion
  (position, quaternion, velocity and angular velocity):
  penalty contact with the hand-written adjoint (``rb.rollout(...,
  adjoint=True)``, what ``sysid.fit`` takes on a CPU) and impulse contact with
  autodiff (it has no adjoint);
* **MJX** and **Brax** (spring and positional pipelines), with respect to the
  box's mass, the friction coefficients and the initial ``qpos``. MJX's
  constraint solver loops in a ``while_loop``, which JAX cannot reverse, so
  its model runs one solver iteration (``opt.iterations = 1``, the workaround
  MuJoCo's issue #2259 names). MuJoCo C has no gradients, and Jax2D and pymunk
  do not run this 3D scene.

Forward and gradient are compiled apart and timed in turn, call by call
(:func:`jaxrb.bench.timing.time_alternated`). Each row also reports whether
every gradient entry is finite, and the loss: the same function of the
motion in every engine, so a value far from the others' is a different
motion (MJX with one solver iteration does not bring the box to rest). Rows
keep ∂loss/∂z0 too, the initial height's entry, whose closed form in free
fall the tests check. It is not compared across engines once the box lands:
the loss is then a sawtooth in the initial height (the step at which the box
first touches moves by one every 5.6 mm, the fall per step at the landing
speed), and each engine's derivative is that of its own smooth pieces.
"""

from __future__ import annotations

import warnings
from typing import Sequence

import jax
import jax.numpy as jnp

from benchmarks.scenes import ENGINE_NAMES, PEER_STEP, PeerRow, drop_mjcf, free_qpos, ratio, world_shifts, x64
from jaxrb.bench import contact, gradients
from jaxrb.bench.report import fmt_fixed, fmt_si, markdown_table
from jaxrb.bench.timing import compile_jitted, time_alternated

#: jaxrb's rows: (contact model, reverse mode), both at the peers' step, one substep.
JAXRB_SETTINGS = (("penalty", "adjoint"), ("impulse", "autodiff"))
#: The State fields jaxrb's gradient is also taken for (its "initial motion"; the rest are not real-valued
#: or, like the impulse solver's warm start, start at zero).
MOTION_FIELDS = ("pos", "quat", "vel", "angvel")


def generalized_loss(qpos, qvel) -> jax.Array:
    """:func:`jaxrb.bench.gradients.trajectory_loss` of one free body's joint trajectory.

    Args:
        qpos: (T, 7) position and (w, x, y, z) quaternion.
        qvel: (T, 6) linear and angular velocity.

    Returns:
        () scalar.
    """
    return (jnp.mean(qpos[:, :3] ** 2) + jnp.mean(qvel[:, :3] ** 2) + jnp.mean(qvel[:, 3:] ** 2)
            + jnp.mean(qpos[:, 4:] ** 2))


def _gradient_row(engine, setting, wrt, loss, args, argnums, height_of, num_steps, batch,
                  settings) -> PeerRow:
    """Compile and time ``loss`` and its gradient; the row's run time is the gradient's.

    Args:
        engine, setting: as :class:`benchmarks.scenes.PeerRow` names them.
        wrt: short text, what the gradient is taken with respect to.
        loss: ``loss(*args) -> ()``.
        args: its arguments.
        argnums: the arguments differentiated.
        height_of: gradient -> ∂loss/∂z0 (a scalar: summed over the worlds' initial heights).
        num_steps: T.
        batch: worlds.
        settings: the section's (``peers_gradient_rounds``, ``peers_budget_s``).
    """
    forward, forward_compile_s = compile_jitted(loss, *args)
    gradient, compile_s = compile_jitted(jax.grad(loss, argnums), *args)
    (forward_s, _, value), (grad_s, _, grads) = time_alternated(
        (forward, gradient), *args, repeats=settings["peers_gradient_rounds"], budget_s=settings["peers_budget_s"])
    return PeerRow("gradient", engine, setting, PEER_STEP, batch, 1, num_steps, compile_s, grad_s, dict(
        wrt=wrt, forward_s=forward_s, forward_compile_s=forward_compile_s, ratio=grad_s / forward_s,
        loss=float(value), finite=gradients.all_finite(grads), height_gradient=float(height_of(grads))))


def jaxrb_gradient(contact_model: str, method: str, num_steps: int, settings: dict, batch: int = 1) -> PeerRow:
    """jaxrb's row: ``contact_model`` at h = 2 ms, ``batch`` worlds, reverse mode ``method`` (gradients.METHODS)."""
    import jaxrb as rb

    model, params, state = contact.drop_scene().build(dtype=jnp.float32, dt=PEER_STEP, contact=contact_model)
    if batch > 1:
        state = contact._batched_state(state, batch)
    state_loss = gradients.make_loss(rb.make_step(model), num_steps, method, batch)
    motion = {name: getattr(state, name) for name in MOTION_FIELDS}

    def loss(params, motion):
        return state_loss(params, state.replace(**motion))

    return _gradient_row("jaxrb", f"{contact_model}, 2 ms, {method}", "every Params field, initial motion", loss,
                         (params, motion), (0, 1), lambda grads: jnp.sum(grads[1]["pos"][..., 0, 2]), num_steps,
                         batch, settings)


def _joint_height(grads):
    return jnp.sum(grads["qpos"][..., 2])


def mjx_gradient(mods: dict, num_steps: int, settings: dict) -> PeerRow:
    """MJX's row: ``mjx.step`` scanned, one solver iteration (see the module docstring)."""
    mujoco, mjx = mods["mujoco"], mods["mjx"]
    with x64(False):
        model = mujoco.MjModel.from_xml_string(drop_mjcf())
        model.opt.iterations = 1
        mx = mjx.put_model(model)
        data0 = mjx.make_data(mx)
        theta = dict(mass=mx.body_mass, friction=mx.geom_friction, qpos=jnp.asarray(model.qpos0, jnp.float32))

        def loss(theta):
            stepped = mx.replace(body_mass=theta["mass"], geom_friction=theta["friction"])

            def one(data, _):
                data = mjx.step(stepped, data)
                return data, (data.qpos, data.qvel)

            _, (qpos, qvel) = jax.lax.scan(one, data0.replace(qpos=theta["qpos"]), None, length=num_steps)
            return generalized_loss(qpos, qvel)

        return _gradient_row("mjx", "Euler, 1 solver iteration", "mass, friction, initial qpos", loss, (theta,),
                             0, _joint_height, num_steps, 1, settings)


def brax_gradient(engine: str, mods: dict, num_steps: int, settings: dict, batch: int = 1) -> PeerRow:
    """Brax's row, ``batch`` worlds (``engine``: ``"brax_spring"`` or ``"brax_positional"``; ``pipeline.step``)."""
    mjcf, pipeline = mods["mjcf"], mods["pipeline"]
    with x64(False), warnings.catch_warnings():
        warnings.simplefilter("ignore")  # Brax warns that it is unmaintained on every load
        system = mjcf.loads(drop_mjcf())
        zero_qd = jnp.zeros(system.qd_size(), jnp.float32)
        act = jnp.zeros(system.act_size(), jnp.float32)
        qpos = system.init_q if batch == 1 else free_qpos(system.init_q, 1, world_shifts(batch, 3))
        theta = dict(mass=system.link.inertia.mass, friction=system.geom_friction, qpos=jnp.asarray(qpos, jnp.float32))

        def loss(theta):
            stepped = system.replace(geom_friction=theta["friction"]).tree_replace(
                {"link.inertia.mass": theta["mass"]})

            def one(state, _):
                state = pipeline.step(stepped, state, act)
                return state, (state.q, state.qd)

            def world(start):
                _, (qpos, qvel) = jax.lax.scan(one, pipeline.init(stepped, start, zero_qd), None, length=num_steps)
                return generalized_loss(qpos, qvel)

            return world(theta["qpos"]) if batch == 1 else jnp.mean(jax.vmap(world)(theta["qpos"]))

        return _gradient_row(engine, "pipeline.step, system from MJCF", "mass, friction, initial qpos", loss,
                             (theta,), 0, _joint_height, num_steps, batch, settings)


def gradient_table(rows: Sequence[PeerRow]) -> str:
    """Markdown table of the gradient rows: times, ratio to the forward, finiteness and jaxrb's speed over each.

    Args:
        rows: all rows (other scenes are ignored).

    Returns:
        The table, its rows by batch; one speed column per jaxrb setting: its
        gradient's body-steps/s over the row's at the same batch (— where it
        has no row at that batch).
    """
    chosen = sorted((r for r in rows if r.scene == "gradient"), key=lambda r: (r.batch, r.engine != "jaxrb"))
    settings = list(dict.fromkeys(r.setting for r in chosen if r.engine == "jaxrb"))
    headers = (["engine", "setting", "worlds", "with respect to", "forward (ms)", "gradient (ms)",
                "gradient / forward", "gradient body-steps/s", "compile: forward, gradient (s)", "all finite",
                "loss"] + [f"jaxrb {setting} / this" for setting in settings])
    table_rows = []
    for row in chosen:
        m = row.metrics
        speeds = []
        for setting in settings:
            mine = [r for r in chosen if r.engine == "jaxrb" and r.setting == setting and r.batch == row.batch]
            speeds.append(fmt_fixed(ratio(mine[0].body_steps_per_s, row.body_steps_per_s), 1) + "×"
                          if mine else "—")
        table_rows.append(
            [ENGINE_NAMES[row.engine], row.setting, row.batch, m["wrt"], fmt_fixed(1e3 * m["forward_s"], 2),
             fmt_fixed(1e3 * row.run_s, 2), fmt_fixed(m["ratio"], 2) + "×", fmt_si(row.body_steps_per_s),
             f"{fmt_fixed(m['forward_compile_s'], 1)}, {fmt_fixed(row.compile_s, 1)}",
             "yes" if m["finite"] else "**NO**", fmt_fixed(m["loss"], 4)] + speeds)
    return markdown_table(headers, table_rows, align=["l", "l", "r", "l"] + ["r"] * (len(headers) - 4))
