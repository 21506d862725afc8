# %% [markdown]
# # Speed against error: which integrator, which step size?
#
# The torque-free intermediate-axis flip (inertia (0.3, 0.35, 0.4), ω₀ = (0.1, 15, 0.1))
# run with every integrator at several step sizes. Error: the largest difference
# between simulated and closed-form flip times (`rb.analytic.flip_times`). Cost: wall
# seconds per simulated second of the jitted rollout (compile excluded, median of
# several runs). Points no other point beats on both are the Pareto front.
# `python -m jaxrb.bench` measures this and more (contact scenes, batches, gradients).

# %%
import os
import pathlib

import jax
import matplotlib.pyplot as plt
import numpy as np

import jaxrb as rb
from jaxrb.bench.free_body import TUMBLE_ANGVEL, TUMBLE_INERTIA, run_tumble
from jaxrb.bench.pareto import pareto_front, plot_speed_vs_error

QUICK = os.environ.get("JAXRB_QUICK") == "1"  # the test suite runs every example small
OUT = pathlib.Path(os.environ.get("JAXRB_OUT", "out"))
OUT.mkdir(parents=True, exist_ok=True)
jax.config.update("jax_enable_x64", True)

# %%
seconds = 8.0 if QUICK else 20.0
steps = (1 / 60, 1 / 240) if QUICK else (1 / 60, 1 / 120, 1 / 240, 1 / 480, 1 / 1000)
reference = rb.analytic.flip_times(TUMBLE_INERTIA, TUMBLE_ANGVEL, seconds)
rows = []
for integrator in ("semi_implicit", "implicit_gyro", "rk4"):
    for h in steps:
        result = run_tumble(integrator, None, h, seconds, "float64", reference, repeats=3)
        cost = result.run_s / seconds
        rows.append((integrator, h, cost, result.flips.max_error))
        print(f"{integrator:14s} h = 1/{round(1 / h):<5d} {cost:.2e} s per simulated s, "
              f"flip error {result.flips.max_error:.2e} s")
integrators, hs, costs, errors = zip(*rows)
best = [f"{g} 1/{round(1 / h)}" for g, h, front in zip(integrators, hs, pareto_front(costs, errors)) if front]
print("Pareto front:", ", ".join(best))

# %%
fig, ax = plt.subplots(figsize=(7, 4.5))
plot_speed_vs_error(ax, costs, errors, [f"1/{round(1 / h)}" for h in hs], integrators,
                    ylabel="largest flip-time error (s)",
                    title=f"torque-free flip, float64, {seconds:g} s")
fig.savefig(OUT / "speed_vs_error.png", dpi=100)
