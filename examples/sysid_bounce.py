"""Fit a ball's restitution to a noisy bounce with optax (about a minute on a CPU; gives 0.682 for 0.7).

    python examples/sysid_bounce.py
"""

import os

import jax
import numpy as np
import optax

import jaxrb as rb
from jaxrb import sysid

jax.config.update("jax_enable_x64", True)
QUICK = os.environ.get("JAXRB_QUICK") == "1"  # the test suite runs every example small

scene = rb.Scene(dim=3)
scene.add_plane(restitution=0.0)  # contacts mix restitution as max(e_A, e_B): the ball's decides
scene.add_body(rb.Sphere(0.1), mass=1.0, pos=(0.0, 0.0, 0.6), vel=(0.3, 0.0, 0.0), restitution=0.7)
# Penalty contact: smooth in restitution, so its gradients suit fitting.
model, truth, state = scene.build(contact="penalty", dt=1e-3)
step = rb.make_step(model)

# "Measurements": positions every 20 ms for 1.2 s with 5 mm noise.
traj = jax.jit(lambda s, p: rb.rollout(step, s, p, 1200, every=20))(state, truth)
observed = sysid.observe(traj, every=20)
observed = observed.replace(pos=observed.pos + 0.005 * np.random.default_rng(0).normal(size=observed.pos.shape))

result = sysid.fit(step, truth.replace(restitution=truth.restitution * 0.5), state, observed,
                   fields="restitution", optimizer=optax.adam(0.05), num_steps=20 if QUICK else 500,
                   log_every=50)  # no early stop: the loss plateaus for ~150 steps on the way
print(f"restitution: fitted {float(result.params.restitution[0]):.4f}, true 0.7, "
      f"{result.steps} steps, best loss {result.losses.min():.3e}")
