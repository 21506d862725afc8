# %% [markdown]
# # Fitting 400 real elbow tosses: joints and contact on measured data
#
# Two 0.1 m blocks on a hinge (the "elbow"), thrown by hand onto a table and
# tracked at 148 Hz (DAIR Lab; data, licence and protocol in
# `examples/elbow_tosses/`). The tracker records link 1's pose and the hinge
# angle; jaxrb reads them as joint coordinates and places link 2 by the
# model's own kinematics. Half the tosses fit the contact; the other half
# score the fitted model the way the data's README scores simulators: each
# toss simulated from three samples before first contact to its end, from a
# state estimated before contact. `JAXRB_QUICK=1` uses 8 tosses of each half.

# %%
import os

import matplotlib.pyplot as plt
import numpy as np

import jaxrb as rb
from jaxrb import evaluate, fit_data

QUICK = os.environ.get("JAXRB_QUICK") == "1"
OUT = os.environ.get("JAXRB_OUT", "out")
os.makedirs(OUT, exist_ok=True)
FOLDER = os.path.join(os.path.dirname(os.path.dirname(rb.__file__)), "examples", "elbow_tosses")
SCENE = os.path.join(FOLDER, "elbow.json")
FIELDS = ("plane_friction", "penalty_stiffness", "penalty_damping")

tosses = fit_data.load_for_scene(os.path.join(FOLDER, "elbow_tosses.npz"), SCENE, sample_dt=1 / 148)
train, validation = tosses.split(0.5, seed=0)
if QUICK:
    train, validation = train.subset(range(8)), validation.subset(range(8))
scene_file, model, params, state = fit_data.build_for_data(SCENE, train)
print(model.summary())

# %% [markdown]
# ## The fit
#
# A forward search on full rollouts (no gradient: through a chain of
# impacts the exact gradient is useless, and short horizons pulled friction
# away from what full rollouts want), then a bootstrap over tosses for each
# value's uncertainty.

# %%
fit = fit_data.fit_measured(model, params, state, train, FIELDS, horizons=(), search_width=1.0,
                            refine_rounds=1 if QUICK else 3, progress=print)
print(fit.table())

# %% [markdown]
# ## Scored on the other half, beside the noise floor

# %%
replay = evaluate.prepare_replay(model, fit.params, state, validation)
scores = evaluate.score(replay, fit.params)
print(scores.text())
floor, position_noise, rotation_noise = evaluate.noise_floor(replay, fit.params, draws=1 if QUICK else 4)
print("noise floor (the tracker's noise alone):\n" + floor.text())
evaluate.plot_scores(scores, os.path.join(OUT, "elbow_tosses_errors.png"))

# %% [markdown]
# Measured (dots) against simulated (lines): both links' heights and the
# hinge angle of the best, the median and the worst validation toss.

# %%
simulated = evaluate.simulate(replay.step, fit.params, replay.initial, replay.trajectories.num_samples,
                              replay.every)
measured = replay.trajectories
order = np.argsort(scores.position)
picks = {"best": order[0], "median": order[len(order) // 2], "worst": order[-1]}
figure, axes = plt.subplots(2, 3, figsize=(12, 5.5), sharex="col")
for column, (label, k) in enumerate(picks.items()):
    count = int(measured.length[k])
    time = np.arange(count) * measured.sample_dt
    for link in range(2):
        axes[0, column].plot(time, measured.pos[k, :count, link, 2], ".", color=f"C{link}", markersize=3)
        axes[0, column].plot(time, np.asarray(simulated.pos[k, :count, link, 2]), color=f"C{link}",
                             label=f"link {link + 1}")
    axes[1, column].plot(time, measured.qpos[k, :count, 7], ".", color="C2", markersize=3)
    axes[1, column].plot(time, np.asarray(simulated.qpos[k, :count, 7]), color="C2")
    axes[0, column].set(title=f"{label}: toss {measured.ids[k]}, {scores.position[k]:.0f} %, "
                              f"{scores.rotation[k]:.0f}°")
    axes[1, column].set(xlabel="t (s)")
axes[0, 0].set_ylabel("centre height (m)")
axes[1, 0].set_ylabel("hinge angle (rad)")
axes[0, 0].legend(frameon=False)
figure.tight_layout()
figure.savefig(os.path.join(OUT, "elbow_tosses_trajectories.png"), dpi=100)

# %% [markdown]
# The median toss, the real elbow (measured poses) beside the simulated one.

# %%
k = picks["median"]
count = int(measured.length[k])
pair = rb.Scene(dim=3)
pair.add_plane(normal=(0, 0, 1))
for name in ("simulated link 1", "simulated link 2", "real link 1", "real link 2"):
    pair.add_body(rb.Box(half_extents=(0.05, 0.025, 0.025)), mass=0.37, name=name)
pair_model, pair_params, _ = pair.build(dt=measured.sample_dt)
beside = np.array([0.0, 0.35, 0.0])
pos = np.concatenate([np.asarray(simulated.pos[k, :count]), measured.pos[k, :count] + beside], axis=1)
quat = np.concatenate([np.asarray(simulated.quat[k, :count]), measured.quat[k, :count]], axis=1)
frames = rb.State(pos=pos, quat=quat, vel=np.zeros_like(pos), angvel=np.zeros_like(pos), angle=None,
                  time=np.arange(count) * measured.sample_dt)
animation = rb.render.animate(pair_model, pair_params, frames, every=2, speed=0.5,
                              title="simulated (left), real (right), half speed;")
rb.render.save_animation(animation, os.path.join(OUT, "elbow_tosses.gif"))
