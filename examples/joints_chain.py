# %% [markdown]
# # Joints: a falling chain and Newton's cradle
#
# Two mechanisms built from hinges (see the guide page `docs/guide/joints.md`):
#
# 1. a chain of capsules hinged end to end and to the world, released horizontal:
#    which integrator keeps it stable at which step, and what it does to the energy;
# 2. Newton's cradle: five balls, each hinged to the world above it, touching, with
#    restitution 1 and no friction; the first is pulled aside 30° and let go.
#
# Run as a script (`python examples/joints_chain.py`, pictures go to `out/`) or as the
# notebook `notebooks/joints_chain.ipynb` made from this file.

# %%
import os
import pathlib

import jax
import jax.numpy as jnp
import matplotlib.pyplot as plt
import numpy as np

import jaxrb as rb

QUICK = os.environ.get("JAXRB_QUICK") == "1"  # the test suite runs every example small
OUT = pathlib.Path(os.environ.get("JAXRB_OUT", "out"))
OUT.mkdir(parents=True, exist_ok=True)
plt.rcParams["animation.html"] = "jshtml"  # in a notebook an animation shows itself

# %% [markdown]
# ## A chain released horizontal
#
# `links` capsules of 0.1 m and 0.1 kg lie along +x. Link 0 is hinged to the world at
# the origin, each next link to the one before it at their common end, every hinge
# about y, so the chain swings in the x–z plane. A joint's `anchor` and `axis` are
# world values at the pose the scene is built in. Links do not collide here
# (`contact="none"`): the chain passes through itself where it folds.

# %%
LINKS = 10 if QUICK else 20
SECONDS = 3.0
LENGTH, MASS = 0.1, 0.1  # per link
ALONG_X = (np.cos(np.pi / 4), 0.0, np.sin(np.pi / 4), 0.0)  # a capsule's axis is its z: turn it onto x


def chain(integrator, dt, links=LINKS, seconds=SECONDS):
    """Build the chain and roll it out; returns (model, params, state, traj)."""
    scene = rb.Scene(dim=3)
    parent = None  # the world
    for i in range(links):
        link = scene.add_body(rb.Capsule(radius=0.02, half_length=LENGTH / 2), mass=MASS,
                              pos=((i + 0.5) * LENGTH, 0.0, 0.0), quat=ALONG_X)
        scene.add_joint(rb.Hinge(axis=(0, 1, 0), anchor=(i * LENGTH, 0, 0)), link, parent)
        parent = link
    model, params, state = scene.build(dt=dt, integrator=integrator, contact="none")
    step = rb.make_step(model)
    traj = jax.jit(lambda s, p: rb.rollout(step, s, p, int(round(seconds / dt))))(state, params)
    return model, params, state, traj


def energy(model, params, states):
    """Total kinetic + potential energy (J) of each state along the leading axis."""
    total = lambda s: jnp.sum(rb.kinetic_energy(model, params, s) + rb.potential_energy(model, params, s))
    return np.asarray(jax.vmap(total)(states))


# The energy the fall can release: the chain's centre of mass drops by half its length.
released = LINKS * MASS * 9.81 * LINKS * LENGTH / 2
runs = {}
print(f"{LINKS} links; energy changes in % of the {released:.1f} J the fall releases")
for integrator, rate in (("implicit", 60), ("midpoint", 60), ("midpoint", 240), ("rk4", 240)):
    model, params, state, traj = chain(integrator, 1 / rate)
    e = energy(model, params, traj) - energy(model, params, jax.tree_util.tree_map(lambda a: a[None], state))[0]
    runs[f"{integrator}, 1/{rate} s"] = (model, params, state, traj, e)
    broken = np.nonzero(~np.isfinite(e))[0]
    if len(broken):
        verdict = f"diverges: NaN from t = {float(traj.time[broken[0]]):.2f} s"
    else:
        whip = float(np.max(np.abs(np.asarray(traj.qvel))))
        verdict = (f"stable; after {SECONDS:.0f} s {100 * e[-1] / released:+5.1f} %, "
                   f"largest change {100 * np.max(np.abs(e)) / released:4.1f} %; "
                   f"fastest hinge {whip:3.0f} rad/s ({whip / rate:.2f} rad a step)")
    print(f"  {integrator:8s} at 1/{rate} s: {verdict}")

# %% [markdown]
# **Which integrator.** For a long chain at a large step such as 1/60 s, use
# `integrator="implicit"`: taking the velocity terms implicitly keeps it stable, at the
# price of numerical damping (the energy it loses above is not physics: the whip is damped
# away). The default, `"midpoint"`, diverges at 1/60 s: as the chain folds, its free end
# whips round at a hundred rad/s and more, and midpoint needs a step about four times
# smaller (1/240 s) to stay stable; even there its energy jumps, by up to tens of per
# cent, whenever the end whips round. Where the energy matters, use `"rk4"` (it takes no
# contact, and there is none here): at the same 1/240 s it keeps the energy to a few per
# cent, and to a tenth of that at half the step.

# %%
fig, ax = plt.subplots(figsize=(8, 3.5))
for label, (*_, traj, e) in runs.items():
    ax.plot(np.asarray(traj.time), 100 * e / released, label=label)
ax.set_ylim(-50, 30)
ax.axhline(0.0, color="k", lw=0.8)
ax.set_xlabel("time (s)")
ax.set_ylabel("energy change (% of release)")
ax.set_title(f"{LINKS}-link chain released horizontal (midpoint at 1/60 s: line ends where it diverges)")
ax.legend(fontsize="small")
fig.tight_layout()
fig.savefig(OUT / "joints_chain_energy.png", dpi=100)

# %%
model, params, state, traj, _ = runs["implicit, 1/60 s"]
anim = rb.render.animate(model, params, traj, initial=state, max_fps=15, view=(0, -90), figsize=(6, 3.5),
                         title=f"{LINKS}-link chain, implicit, 1/60 s")
anim.jaxrb_painter.ax.set_yticks([])  # seen side on, y's labels would pile up in one place
rb.render.save_animation(anim, OUT / "joints_chain.gif")
anim

# %% [markdown]
# ## Newton's cradle
#
# Five 0.1 kg balls of radius 2.5 cm hang 0.3 m below their hinges, touching, with
# restitution 1 and friction 0. The first is released from 30°. In a real cradle the
# impact goes through the row and the last ball alone swings out, as high as the first
# was released; `cradle` measures how high each ball rises.

# %%
def cradle(balls=5, radius=0.025, length=0.3, angle_deg=30.0, dt=1 / 60, seconds=1.0):
    """Roll out the cradle; return (model, params, state, traj, rises).

    ``rises`` (balls,) is each ball's highest rise above its rest height over the run,
    divided by the first ball's release height; ``seconds=1.0`` covers the first
    impact and the last ball's swing out (up at about 0.55 s), not its return.
    """
    scene = rb.Scene(dim=3)
    for i in range(balls):
        x = 2 * radius * i
        ball = scene.add_body(rb.Sphere(radius), mass=0.1, pos=(x, 0.0, -length),
                              restitution=1.0, friction=0.0)
        scene.add_joint(rb.Hinge(axis=(0, 1, 0), anchor=(x, 0, 0)), ball)
    model, params, state = scene.build(dt=dt)  # impulse contact, 8 substeps at 1/60 s
    pulled = jnp.zeros(balls).at[0].set(np.radians(angle_deg))  # +about y: the first ball swings to -x
    state = rb.joints.set_qpos_qvel(model, params, state, pulled, jnp.zeros(balls))
    step = rb.make_step(model)
    traj = jax.jit(lambda s, p: rb.rollout(step, s, p, int(round(seconds / dt))))(state, params)
    release = length * (1 - np.cos(np.radians(angle_deg)))
    rises = (np.asarray(traj.pos[:, :, 2]).max(axis=0) + length) / release
    return model, params, state, traj, rises


model, params, state, traj, rises = cradle()
print(f"last ball rises to {rises[-1]:.4f} of the first ball's release height "
      f"(sampled every 1/60 s; the true peak can fall between samples)")
print("middle balls' highest rise, fraction of that height:", np.array2string(rises[1:-1], precision=6))

# %% [markdown]
# The impact passes through the row: the last ball swings out to the first ball's release
# height (to the 1/60 s sampling of its peak) while the three in the middle stay put (they
# move by micrometres). The impulse solver carries an impact contact by contact along the
# row, each with Newton's restitution, so the momentum is not shared among the touching
# balls. Below, the first second: in, impact, out.

# %%
anim2 = rb.render.animate(model, params, traj, initial=state, view=(0, -90), figsize=(6, 3),
                          title="Newton's cradle")
anim2.jaxrb_painter.ax.set_yticks([])
rb.render.save_animation(anim2, OUT / "newtons_cradle.gif")
anim2
