# %% [markdown]
# # Bouncing, sliding and stacking with both contact models
#
# jaxrb has two contact models. **Impulse** contact (the default) changes velocities
# with impulses at each substep: sequential impulses with restitution, Coulomb friction
# and a soft position correction; it takes large steps (1/60 s × 4 substeps).
# **Penalty** contact pushes with a spring-damper on the overlap: smooth, cheap per step,
# but stiff, so it needs small steps (1 ms). Each scene is compared with its closed form.

# %%
import os
import pathlib

import jax
import matplotlib.pyplot as plt
import numpy as np

import jaxrb as rb

QUICK = os.environ.get("JAXRB_QUICK") == "1"  # the test suite runs every example small
OUT = pathlib.Path(os.environ.get("JAXRB_OUT", "out"))
OUT.mkdir(parents=True, exist_ok=True)
jax.config.update("jax_enable_x64", True)

MODELS = {  # build settings of each contact model
    "impulse": dict(contact=rb.Impulse(time_of_impact=True), dt=1 / 240, substeps=4),
    "penalty": dict(contact="penalty", dt=1e-3),
}


def simulate(scene, seconds, settings):
    """Build ``scene`` with ``settings`` and roll it out for ``seconds``; returns the trajectory."""
    model, params, state = scene.build(**settings)
    step = rb.make_step(model)
    num_steps = int(round(seconds / settings["dt"]))
    return jax.jit(lambda s, p: rb.rollout(step, s, p, num_steps))(state, params)


# %% [markdown]
# ## Bouncing ball: apexes at h·e^(2k)
#
# A ball of radius 0.1 m dropped from 0.9 m (lowest point) with restitution 0.8.

# %%
ball = rb.Scene(dim=3)
ball.add_plane()
ball.add_body(rb.Sphere(0.1), mass=1.0, pos=(0.0, 0.0, 1.0), restitution=0.8)
expected = rb.analytic.bounce_apexes(0.9, 0.8, 3)

fig, ax = plt.subplots(figsize=(8, 3.5))
for name, settings in MODELS.items():
    traj = simulate(ball, 2.0 if QUICK else 3.0, settings)
    height = np.asarray(traj.pos[:, 0, 2]) - 0.1
    rising = np.asarray(traj.vel[:, 0, 2])
    apexes = height[1:][(rising[:-1] > 0) & (rising[1:] <= 0)][: len(expected)]
    errors = ", ".join(f"{100 * (a / e - 1):+.2f} %" for a, e in zip(apexes, expected))
    print(f"bounce, {name}: apex errors {errors}")
    ax.plot(np.asarray(traj.time), height, label=name)
for apex in expected:
    ax.axhline(apex, color="k", lw=0.6, ls="--")
ax.set(xlabel="t (s)", ylabel="lowest point (m)", title="bouncing ball; dashed: 0.9·0.8^(2k)")
ax.legend()
fig.savefig(OUT / "contact_bounce.png", dpi=100)

# %% [markdown]
# ## Sliding box: stops after v²/(2μg)

# %%
slide = rb.Scene(dim=3)
slide.add_plane(friction=0.5)
slide.add_body(rb.Box((0.1, 0.1, 0.1)), mass=1.0, pos=(0.0, 0.0, 0.1), vel=(2.0, 0.0, 0.0),
               friction=0.5)
distance = rb.analytic.slide_distance(2.0, 0.5)
for name, settings in MODELS.items():
    traj = simulate(slide, 1.0, settings)
    travelled = float(traj.pos[-1, 0, 0])
    print(f"slide, {name}: {travelled:.4f} m, closed form {distance:.4f} m "
          f"({100 * (travelled / distance - 1):+.2f} %)")

# %% [markdown]
# ## A column of boxes that stays still

# %%
count = 3 if QUICK else 6
column = rb.Scene(dim=3)
column.add_plane()
for level in range(count):
    column.add_body(rb.Box((0.1, 0.1, 0.1)), mass=1.0, pos=(0.0, 0.0, 0.1 + 0.2 * level))
fig, axes = plt.subplots(1, 2, figsize=(8, 4), subplot_kw={"projection": "3d"})
for ax, (name, settings) in zip(axes, MODELS.items()):
    settings = dict(settings, contact=rb.Impulse()) if name == "impulse" else settings
    model, params, state = column.build(**settings)
    traj = simulate(column, 2.0, settings)
    sink = 1000 * float(state.pos[-1, 2] - traj.pos[-1, -1, 2])
    sideways = 1000 * float(np.abs(np.asarray(traj.pos[-1, :, :2])).max())
    print(f"{count}-box column, {name}: top box sank {sink:.2f} mm, moved {sideways:.3f} mm sideways")
    rb.render.draw(model, params, jax.tree_util.tree_map(lambda a: a[-1], traj), ax=ax,
                   title=f"{name} after 2 s")
fig.savefig(OUT / "contact_stack.png", dpi=100)
