# %% [markdown]
# # The intermediate-axis (Dzhanibekov) flip
#
# A free body spun about the axis of its middle principal moment does not keep
# spinning about it: every few seconds it turns over. Euler's equations have a
# closed-form solution in Jacobi elliptic functions, so the flip times are known
# exactly (`rb.analytic.flip_times`) and each integrator can be measured against them.

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
jax.config.update("jax_enable_x64", True)  # float64, so the error is the integrator's

# %%
inertia, angvel0 = (0.3, 0.35, 0.4), (0.1, 15.0, 0.1)
seconds, dt = (10.0 if QUICK else 20.0), 1 / 240
reference = rb.analytic.flip_times(inertia, angvel0, seconds)
print("closed-form flip times (s):", np.round(reference, 4))

scene = rb.Scene(dim=3, gravity=(0.0, 0.0, 0.0))
scene.add_body(rb.Box((0.5, 0.3, 0.2)), mass=1.0, inertia=inertia, angvel=angvel0)


def body_angvel(integrator):
    """Body-frame ω over time, (T, 3), for one integrator."""
    model, params, state = scene.build(dt=dt, integrator=integrator)
    step = rb.make_step(model)
    traj = jax.jit(lambda s, p: rb.rollout(step, s, p, int(round(seconds / dt))))(state, params)
    return traj.time, rb.quaternion.rotate_inverse(traj.quat[:, 0], traj.angvel[:, 0])


def crossings(times, values):
    """Times where ``values`` changes sign, linearly interpolated."""
    times, values = np.asarray(times), np.asarray(values)
    i = np.nonzero(np.sign(values[1:]) != np.sign(values[:-1]))[0]
    return times[i] - values[i] * (times[i + 1] - times[i]) / (values[i + 1] - values[i])


results = {name: body_angvel(name) for name in ("semi_implicit", "implicit_gyro", "rk4")}
for name, (times, omega) in results.items():
    flips = crossings(times, omega[:, 1])
    if len(flips) == len(reference):
        verdict = f"largest error {np.max(np.abs(flips - reference)):.2e} s"
    else:  # semi_implicit gains energy at this spin and h, and leaves the orbit
        verdict = f"{len(flips)} flips instead of {len(reference)}"
    print(f"{name:14s} flips at {np.round(flips, 3)}  {verdict}")

# %%
times, omega = results["rk4"]
fig, ax = plt.subplots(figsize=(8, 3.5))
rb.render.plot_series(times, omega, labels=["ω₁ (0.30)", "ω₂ (0.35, middle)", "ω₃ (0.40)"],
                      ax=ax, ylabel="body-frame ω (rad/s)")
for t in reference:
    ax.axvline(t, color="k", lw=0.8, ls="--")
ax.set_title("RK4, h = 1/240 s; dashed: closed-form flip times")
fig.savefig(OUT / "dzhanibekov.png", dpi=100)
