# %% [markdown]
# # System identification: friction and restitution from noisy trajectories
#
# Three throws of a 2D box onto the ground (a drop, a low slide, a tumble) are
# "measured": positions and angles every 10 ms with 1 cm of noise. Starting from
# half the true friction and restitution, `rb.sysid.fit` differentiates the loss
# through the whole contact-rich rollout (penalty contact, 1 ms steps) and fits
# both with Adam. The three throws share one parameter set and are vmapped.

# %%
import os
import pathlib

import jax
import jax.numpy as jnp
import matplotlib.pyplot as plt
import numpy as np
import optax

import jaxrb as rb
from jaxrb import sysid

QUICK = os.environ.get("JAXRB_QUICK") == "1"  # the test suite runs every example small
OUT = pathlib.Path(os.environ.get("JAXRB_OUT", "out"))
OUT.mkdir(parents=True, exist_ok=True)

# %%
throws = [dict(pos=(0.0, 0.8), angle=0.05, vel=(0.5, 0.0), angvel=0.0),
          dict(pos=(0.0, 0.15), angle=0.05, vel=(3.0, 0.0), angvel=0.0),
          dict(pos=(0.0, 0.4), angle=0.3, vel=(1.5, 0.0), angvel=2.0)]
states = []
for throw in throws:
    scene = rb.Scene(dim=2)
    scene.add_plane(friction=1.0, restitution=0.0)  # mixing √(μ_A μ_B) and max(e_A, e_B): the box decides
    scene.add_body(rb.Box((0.2, 0.1)), mass=1.0, friction=0.3, restitution=0.5, **throw)
    model, truth, state = scene.build(contact="penalty", dt=1e-3)
    states.append(state)
starts = jax.tree_util.tree_map(lambda *leaves: jnp.stack(leaves), *states)
step = rb.make_step(model)
simulate = jax.jit(jax.vmap(lambda s, p: rb.rollout(step, s, p, 800, every=10), in_axes=(0, None)))
truth_traj = simulate(starts, truth)

noise = np.random.default_rng(0).normal(scale=0.01, size=truth_traj.pos.shape)
observed = jax.vmap(lambda t: sysid.observe(t, every=10))(truth_traj)
observed = observed.replace(pos=observed.pos + noise)

# %%
history = []
result = sysid.fit(step, truth.replace(friction=truth.friction * 0.5, restitution=truth.restitution * 0.5),
                   starts, observed, fields=("friction", "restitution"), optimizer=optax.adam(0.05),
                   num_steps=20 if QUICK else 200, tol=1e-4, patience=50,
                   callback=lambda k, loss, p: history.append(
                       (float(p.friction[0]), float(p.restitution[0]))))
fitted = result.params
print(f"friction    fitted {float(fitted.friction[0]):.4f}  true 0.3")
print(f"restitution fitted {float(fitted.restitution[0]):.4f}  true 0.5  ({result.steps} Adam steps)")

# %%
fitted_traj = simulate(starts, fitted)
fig, axes = plt.subplots(1, 3, figsize=(12, 3.5))
axes[0].semilogy(result.losses)
axes[0].set(xlabel="Adam step", ylabel="loss", title="loss")
history = np.array(history)
for column, (name, true_value) in enumerate([("friction", 0.3), ("restitution", 0.5)]):
    axes[1].plot(history[:, column], label=name)
    axes[1].axhline(true_value, color=f"C{column}", ls="--", lw=0.8)
axes[1].set(xlabel="Adam step", title="parameters (dashed: true)")
axes[1].legend()
times = np.asarray(truth_traj.time[0])
for throw in range(len(throws)):
    axes[2].plot(times, observed.pos[throw, :, 0, 1], ".", ms=2, color=f"C{throw}")
    axes[2].plot(times, fitted_traj.pos[throw, :, 0, 1], color=f"C{throw}", label=f"throw {throw}")
axes[2].set(xlabel="t (s)", ylabel="height (m)", title="observed (dots) vs fitted")
axes[2].legend()
fig.tight_layout()
fig.savefig(OUT / "system_identification.png", dpi=100)
