# %% [markdown]
# # Gymnasium's hopper in jaxrb
#
# `rb.load_scene` compiles an MJCF file with MuJoCo itself and maps what MuJoCo built:
# bodies with MuJoCo's inertias, the geoms placed in them, joints, actuators, contact
# filtering. Here gymnasium's `hopper.xml` (a torso on two slides and a hinge, then
# thigh, leg and foot on hinges, three motors) is loaded, driven open loop for a couple of
# seconds, drawn, and checked against MuJoCo. Needs `gymnasium` and `mujoco`
# (`pip install -e ".[dev]"`). Run as a script (`python examples/gym_hopper.py`,
# pictures go to `out/`) or as the notebook `notebooks/gym_hopper.ipynb`.

# %%
import os
import pathlib

import gymnasium
import jax
import jax.numpy as jnp
import matplotlib.pyplot as plt
import mujoco
import numpy as np

import jaxrb as rb
from jaxrb.files import mjcf

QUICK = os.environ.get("JAXRB_QUICK") == "1"  # the test suite runs every example small
OUT = pathlib.Path(os.environ.get("JAXRB_OUT", "out"))
OUT.mkdir(parents=True, exist_ok=True)
plt.rcParams["animation.html"] = "jshtml"  # in a notebook an animation shows itself
jax.config.update("jax_enable_x64", True)  # float64, so the comparison with MuJoCo is to rounding

# %% [markdown]
# ## Load it
#
# The file's options become build options (MuJoCo's 2 ms step; its RK4 is replaced by
# jaxrb's `midpoint`, since jaxrb's `rk4` takes no contact), and whatever jaxrb
# approximates is listed as a warning rather than dropped silently.

# %%
PATH = os.path.join(os.path.dirname(gymnasium.__file__), "envs", "mujoco", "assets", "hopper.xml")
hopper = rb.load_scene(PATH)
print("build options:", hopper.build_options)
for warning in hopper.warnings:
    print("warning:", warning)
model, params, state = hopper.build()
print(model.summary())

# %% [markdown]
# ## MuJoCo's coordinates
#
# `State.qpos` and `State.qvel` are laid out as MuJoCo lays out the same model, joint by
# joint; `rb.joints.qpos_qvel` reads them and `rb.joints.set_qpos_qvel` writes them. Below,
# the initial coordinates beside MuJoCo's `qpos0`; then a random pose written into both
# engines puts every body's centre of mass in the same place.

# %%
mj_model = mujoco.MjModel.from_xml_path(PATH)
qpos, qvel = rb.joints.qpos_qvel(model, params, state)
print(f"{'joint':12s} {'kind':6s} {'jaxrb qpos':>10s} {'MuJoCo qpos0':>12s}")
for j in range(mj_model.njnt):
    kind = {2: "slide", 3: "hinge"}[int(mj_model.jnt_type[j])]
    address = mj_model.jnt_qposadr[j]
    print(f"{mj_model.joint(j).name:12s} {kind:6s} {float(qpos[address]):10.4f} {mj_model.qpos0[address]:12.4f}")

rng = np.random.default_rng(0)
random_qpos = mj_model.qpos0 + rng.uniform(-0.5, 0.5, mj_model.nq)
moved = rb.joints.set_qpos_qvel(model, params, state, jnp.asarray(random_qpos), jnp.zeros(mj_model.nv))
mj_data = mujoco.MjData(mj_model)
mj_data.qpos[:] = random_qpos
mujoco.mj_forward(mj_model, mj_data)
gap = np.max(np.abs(np.asarray(moved.pos) - mj_data.xipos[1:]))  # MuJoCo's body 0 is the world
print(f"random pose: centres of mass differ from MuJoCo's by at most {gap:.1e} m")

# %% [markdown]
# ## Drive it open loop
#
# Controls are one row per step and one column per actuator, within the file's
# `ctrlrange` (−1 to 1; the motors' gear is 200). All three joints get the same 2 Hz sine:
# the leg folds and unfolds. Open loop a hopper cannot balance: it pitches over and falls
# within a second or so. A policy (or an optimiser, through `jax.grad`) would close the
# loop with the same `controls` argument.

# %%
SECONDS = 1.0 if QUICK else 2.0
dt = float(params.dt)
steps = int(round(SECONDS / dt))
t = dt * np.arange(1, steps + 1)
controls = np.repeat(0.2 * np.sin(2 * np.pi * 2.0 * t)[:, None], model.num_actuators, axis=1)
low, high = np.asarray(params.ctrl_range).T
assert controls.shape == (steps, 3) and np.all((low <= controls) & (controls <= high))

step = rb.make_step(model)
traj = jax.jit(lambda s, p, u: rb.rollout(step, s, p, steps, controls=u))(state, params, jnp.asarray(controls))
torso = np.asarray(traj.qpos[:, :3])  # rootx, rootz, rooty: the torso's x, height and pitch
for k in range(int(round(0.25 / dt)) - 1, steps, int(round(0.25 / dt))):
    print(f"t = {float(traj.time[k]):.2f} s: torso x {torso[k, 0]:+.3f} m, height {torso[k, 1]:.3f} m, "
          f"pitch {np.degrees(torso[k, 2]):+6.1f}°")

# %% [markdown]
# The same controls in MuJoCo, with the file's own options (RK4, soft contacts and soft
# limits). The contacts, limits and friction mixing are modelled differently (see
# `docs/guide/mjcf.md`), so the two engines are not expected to agree to rounding here;
# they follow each other through the fall, parting by a few centimetres and degrees once
# the hopper is down.

# %%
mj_data = mujoco.MjData(mj_model)
mj_torso = []
for k in range(steps):
    mj_data.ctrl[:] = controls[k]
    mujoco.mj_step(mj_model, mj_data)
    mj_torso.append(mj_data.qpos[:3].copy())
mj_torso = np.array(mj_torso)
print(f"torso against MuJoCo's over {SECONDS:.0f} s: height within "
      f"{100 * np.max(np.abs(torso[:, 1] - mj_torso[:, 1])):.1f} cm, pitch within "
      f"{np.degrees(np.max(np.abs(torso[:, 2] - mj_torso[:, 2]))):.1f}°")

fig, axes = plt.subplots(1, 2, figsize=(9, 3.2))
for ax, column, label in ((axes[0], 1, "torso height (m)"), (axes[1], 2, "torso pitch (°)")):
    scale = 1.0 if column == 1 else 180 / np.pi
    ax.plot(t, scale * torso[:, column], label="jaxrb")
    ax.plot(t, scale * mj_torso[:, column], "--", label="MuJoCo")
    ax.set_xlabel("time (s)")
    ax.set_ylabel(label)
axes[0].legend()
fig.suptitle("hopper, open-loop 2 Hz sine on all three motors")
fig.tight_layout()
fig.savefig(OUT / "gym_hopper_torso.png", dpi=100)

# %% [markdown]
# ## Draw it
#
# The hopper's thigh and foot capsules are geoms placed in their bodies (`pos`, `quat`): each body's
# frame is MuJoCo's body frame, and its shape sits where the file puts it in that frame
# (`model.shape_frames`). The still shows the hopper half way through the run.

# %%
middle = jax.tree_util.tree_map(lambda a: a[steps // 2], traj)
fig = plt.figure(figsize=(5, 5))
ax = fig.add_subplot(projection="3d")
rb.render.draw(model, params, middle, ax=ax, view=(0, -90), title=f"hopper at t = {float(middle.time):.2f} s")
ax.set_yticks([])  # seen side on, y's labels would pile up in one place
fig.savefig(OUT / "gym_hopper.png", dpi=100)

# %%
anim = rb.render.animate(model, params, traj, initial=state, max_fps=20, view=(0, -90), title="hopper")
anim.jaxrb_painter.ax.set_yticks([])
rb.render.save_animation(anim, OUT / "gym_hopper.gif")
anim

# %% [markdown]
# ## Step for step with MuJoCo's Euler
#
# Away from limits and contact jaxrb's `semi_implicit` integrator is MuJoCo's `Euler`. With
# both switched off in MuJoCo (`disableflags`), the importer builds the scene without them;
# from a random state with random controls the two then step alike to rounding.

# %%
free_model = mujoco.MjModel.from_xml_path(PATH)
free_model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_LIMIT | mujoco.mjtDisableBit.mjDSBL_CONTACT
free_model.opt.integrator = mujoco.mjtIntegrator.mjINT_EULER
free = mjcf.scene_from_mjmodel(free_model, "hopper.xml")
free_jaxrb, free_params, free_state = free.build(contact="none", substeps=1, integrator="semi_implicit")

start_qpos = free_model.qpos0 + rng.uniform(-0.3, 0.3, free_model.nq)
start_qvel = rng.uniform(-1.0, 1.0, free_model.nv)
few = 10
few_controls = rng.uniform(-1.0, 1.0, (few, free_model.nu))
free_state = rb.joints.set_qpos_qvel(free_jaxrb, free_params, free_state, jnp.asarray(start_qpos),
                                     jnp.asarray(start_qvel))
ours = rb.rollout(rb.make_step(free_jaxrb), free_state, free_params, few, controls=jnp.asarray(few_controls))

free_data = mujoco.MjData(free_model)
free_data.qpos[:], free_data.qvel[:] = start_qpos, start_qvel
print("step  |qpos - MuJoCo's|  |qvel - MuJoCo's|   (largest over the 6 coordinates)")
for k in range(few):
    free_data.ctrl[:] = few_controls[k]
    mujoco.mj_step(free_model, free_data)
    qpos_gap = np.max(np.abs(np.asarray(ours.qpos[k]) - free_data.qpos))
    qvel_gap = np.max(np.abs(np.asarray(ours.qvel[k]) - free_data.qvel))
    print(f"{k + 1:4d}  {qpos_gap:17.1e}  {qvel_gap:17.1e}")
