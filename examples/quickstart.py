# %% [markdown]
# # Quickstart: a box dropped in 3D, a pyramid in 2D
#
# Build a scene on the host, get a pure `step(state, params) -> state`, roll it
# out with `lax.scan`, and look at it. Run as a script (`python examples/quickstart.py`,
# pictures go to `out/`) or as the notebook `notebooks/quickstart.ipynb` made from this file.

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
plt.rcParams["animation.html"] = "jshtml"  # in a notebook an animation shows itself

# %% [markdown]
# ## A tilted box dropped onto a plane (impulse contact)
#
# A 0.2 m cube of 1 kg, tilted 30° about x, falls from 0.5 m. The step is 1/60 s split
# into 4 substeps; the contact solver is sequential impulses with restitution 0.

# %%
scene = rb.Scene(dim=3)
scene.add_plane(friction=0.6)
half_turn = np.radians(30.0) / 2
scene.add_body(rb.Box((0.1, 0.1, 0.1)), mass=1.0, pos=(0.0, 0.0, 0.5),
               quat=(np.cos(half_turn), np.sin(half_turn), 0.0, 0.0), angvel=(0.0, 2.0, 0.0))
model, params, state = scene.build(dt=1 / 60, substeps=4)
print(model.summary())

step = rb.make_step(model)
simulate = jax.jit(lambda s, p: rb.rollout(step, s, p, num_steps=120))
traj = simulate(state, params)
print(f"box centre after 2 s: z = {float(traj.pos[-1, 0, 2]):.4f} m (resting face-down: 0.1 m)")

# %%
anim = rb.render.animate(model, params, traj, initial=state, every=2, contacts=True, title="box drop")
rb.render.save_animation(anim, OUT / "quickstart_box.gif")
anim

# %% [markdown]
# ## A 2D pyramid of boxes standing on the ground

# %%
rows = 4 if QUICK else 8
half = 0.1
pyramid = rb.Scene(dim=2)
pyramid.add_plane(friction=0.5)
for row in range(rows):
    for column in range(rows - row):
        x = (column - (rows - 1 - row) / 2) * 2 * half * 1.05
        pyramid.add_body(rb.Box((half, half)), mass=1.0, pos=(x, half + 2 * half * row))
model2, params2, state2 = pyramid.build(dt=1 / 60, substeps=4)
step2 = rb.make_step(model2)
traj2 = jax.jit(lambda s, p: rb.rollout(step2, s, p, num_steps=180))(state2, params2)
drift = np.abs(np.asarray(traj2.pos[-1] - state2.pos)).max()
print(f"{model2.num_bodies} boxes after 3 s: largest displacement {1000 * drift:.2f} mm")

# %%
fig, ax = plt.subplots(figsize=(6, 3.5))
rb.render.draw(model2, params2, jax.tree_util.tree_map(lambda a: a[-1], traj2), ax=ax,
               contacts=True, title="pyramid after 3 s")
fig.savefig(OUT / "quickstart_pyramid.png", dpi=100)

# %%
anim2 = rb.render.animate(model2, params2, traj2, initial=state2, every=6, title="pyramid")
rb.render.save_animation(anim2, OUT / "quickstart_pyramid.gif")
anim2
