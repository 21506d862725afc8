# %% [markdown]
# # A vmapped parameter sweep: where does a thrown box stop?
#
# A 2D box is thrown at 3 m/s, spinning, onto the ground. Where it comes to rest
# depends on friction and restitution in a way no formula gives. `rb.sweep` runs one
# world per (friction, restitution) pair, all in one jitted, vmapped call (and, with
# `shard=True`, spread over every device), and returns only the outcome of each.

# %%
import os
import pathlib
import time

import jax
import jax.numpy as jnp
import matplotlib.pyplot as plt
import numpy as np

import jaxrb as rb
from jaxrb import sweep

QUICK = os.environ.get("JAXRB_QUICK") == "1"  # the test suite runs every example small
OUT = pathlib.Path(os.environ.get("JAXRB_OUT", "out"))
OUT.mkdir(parents=True, exist_ok=True)

# %%
scene = rb.Scene(dim=2)
scene.add_plane(friction=1.0, restitution=0.0)  # the box's own values decide (√(μ_A μ_B), max(e_A, e_B))
scene.add_body(rb.Box((0.15, 0.05)), mass=1.0, pos=(0.0, 0.5), angle=0.3, vel=(3.0, 0.0), angvel=-4.0)
model, params, state = scene.build(dt=1 / 120, substeps=4)  # impulse contact

size = 8 if QUICK else 32
friction, restitution = np.meshgrid(np.linspace(0.05, 1.0, size), np.linspace(0.0, 0.9, size))
batch = sweep.batch_params(params, friction=friction.ravel(), restitution=restitution.ravel())
final_x = sweep.rollout_outcome(rb.make_step(model), 240, lambda traj, p: traj.pos[-1, 0, 0])

start = time.perf_counter()
stops = np.asarray(sweep.sweep(final_x, batch, state=state)).reshape(size, size)
print(f"{size * size} worlds × 240 steps in {time.perf_counter() - start:.1f} s (compile included); "
      f"stopping points {stops.min():.2f} .. {stops.max():.2f} m")

# %%
fig, ax = plt.subplots(figsize=(5.5, 4.5))
image = ax.pcolormesh(friction, restitution, stops, shading="auto", cmap="viridis")
fig.colorbar(image, ax=ax, label="x where the box stops (m)")
ax.set(xlabel="friction μ", ylabel="restitution e", title="thrown box: stopping point after 2 s")
fig.savefig(OUT / "parameter_sweep.png", dpi=100)
