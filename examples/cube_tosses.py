# %% [markdown]
# # Fitting 400 real cube tosses
#
# A cube thrown by hand onto a table, tracked at 148 Hz (DAIR Lab; data and
# licence in `examples/cube_tosses/`). Half the tosses fit jaxrb's contact
# parameters; the other half score the fitted model the way the literature
# scores simulators: each toss simulated for its whole length from a state
# estimated before the cube touches the table. `JAXRB_QUICK=1` uses 6 tosses
# of each half.

# %%
import os

import matplotlib.pyplot as plt
import numpy as np

import jaxrb as rb
from jaxrb import evaluate, fit_data
from jaxrb.fit.measured import load_trajectories

QUICK = os.environ.get("JAXRB_QUICK") == "1"
OUT = os.environ.get("JAXRB_OUT", "out")
os.makedirs(OUT, exist_ok=True)
FOLDER = os.path.join(os.path.dirname(os.path.dirname(rb.__file__)), "examples", "cube_tosses")
FIELDS = ("friction", "penalty_stiffness", "penalty_damping")

tosses = load_trajectories(os.path.join(FOLDER, "cube_tosses.npz"), sample_dt=1 / 148, angvel_frame="body")
train, validation = tosses.split(0.5, seed=0)
if QUICK:
    train, validation = train.subset(range(6)), validation.subset(range(6))
scene_file, model, params, state = fit_data.build_for_data(os.path.join(FOLDER, "cube.json"), train)
print(model.summary())

# %% [markdown]
# ## The fit
#
# Levenberg–Marquardt on short horizons (8, then 32 samples ahead of every
# other measured state), then a forward-only search on full rollouts.

# %%
fit = fit_data.fit_measured(model, params, state, train, FIELDS, time_budget=240,
                            max_iterations=3 if QUICK else 20, progress=print)
print(fit.table())

# %%
figure, axes = plt.subplots(1, 1 + len(FIELDS), figsize=(4 * (1 + len(FIELDS)), 3.2))
stages = list(dict.fromkeys(entry["stage"] for entry in fit.path))
for stage in stages:
    costs = [entry["cost"] for entry in fit.path if entry["stage"] == stage]
    axes[0].plot(np.array(costs) / costs[0], "o-", label=stage)
axes[0].set(xlabel="iteration (LM) or round (search)", ylabel="cost / its first value", title="loss")
axes[0].legend(frameon=False)
for axis, name in zip(axes[1:], FIELDS):
    values = [entry[name][0] for entry in fit.path]
    final = float(np.ravel(getattr(fit.params, name))[0])
    error = float(np.ravel(fit.standard_errors[name])[0])
    axis.plot(values, "o-", color="C0")
    axis.axhspan(final - error, final + error, color="C1", alpha=0.3, label="final ± standard error")
    axis.set(xlabel="step of the fit", title=name)
axes[-1].legend(frameon=False)
figure.tight_layout()
figure.savefig(os.path.join(OUT, "cube_tosses_fit.png"), dpi=100)

# %% [markdown]
# ## Scored on the other half

# %%
replay = evaluate.prepare_replay(model, fit.params, state, validation)
scores = evaluate.score(replay, fit.params)
print(scores.text())
evaluate.plot_scores(scores, os.path.join(OUT, "cube_tosses_errors.png"))

# %% [markdown]
# Measured (dots) against simulated (lines): the best, the median and the
# worst validation toss by position error.

# %%
simulated = evaluate.simulate(replay.step, fit.params, replay.initial, validation.num_samples, replay.every)
order = np.argsort(scores.position)
picks = {"best": order[0], "median": order[len(order) // 2], "worst": order[-1]}
figure, axes = plt.subplots(1, 3, figsize=(12, 3.2), sharey=True)
for axis, (label, k) in zip(axes, picks.items()):
    count = int(validation.length[k])
    time = np.arange(count) * validation.sample_dt
    for c, name in enumerate("xyz"):
        axis.plot(time, validation.pos[k, :count, 0, c], ".", color=f"C{c}", markersize=3)
        axis.plot(time, np.asarray(simulated.pos[k, :count, 0, c]) * replay.length_scale, color=f"C{c}",
                  label=name)
    axis.set(title=f"{label}: toss {validation.ids[k]}, {scores.position[k]:.1f} %", xlabel="t (s)")
axes[0].set_ylabel("position (m)")
axes[0].legend(frameon=False)
figure.tight_layout()
figure.savefig(os.path.join(OUT, "cube_tosses_trajectories.png"), dpi=100)

# %% [markdown]
# The median toss, the real cube (measured poses) beside the simulated one.

# %%
k = picks["median"]
count = int(validation.length[k])
pair = rb.Scene(dim=3)
pair.add_plane(normal=(0, 0, 1))
for name in ("simulated", "real"):
    pair.add_body(rb.Box(half_extents=(0.0524,) * 3), mass=0.37, name=name)
pair_model, pair_params, _ = pair.build(dt=validation.sample_dt)
beside = np.array([0.0, 0.3, 0.0])
pos = np.stack([np.asarray(simulated.pos[k, :count, 0]) * replay.length_scale,
                validation.pos[k, :count, 0] + beside], axis=1)
quat = np.stack([np.asarray(simulated.quat[k, :count, 0]), validation.quat[k, :count, 0]], axis=1)
frames = rb.State(pos=pos, quat=quat, vel=np.zeros_like(pos), angvel=np.zeros_like(pos), angle=None,
                  time=np.arange(count) * validation.sample_dt)
animation = rb.render.animate(pair_model, pair_params, frames, every=2, speed=0.5,
                              title="simulated (blue), real (purple), half speed;")
rb.render.save_animation(animation, os.path.join(OUT, "cube_tosses.gif"))
