"""Speed against error on four scenes with closed-form answers, and their Pareto fronts.

Each configuration the engine offers (integrator and orientation update,
contact model, step size, substeps, solver iterations and scheme, time of
impact, penalty friction law, float64/float32) is run on a scene whose answer
is known in closed form (:mod:`jaxrb.analytic`) and scored on two axes:

* **error** against the closed form, one scalar per scene (the scenes and how
  each error is measured: :mod:`jaxrb.bench.speed_error.scenes`);
* **cost**: seconds of wall time per simulated second at batch 1, beside the
  compile time and the body-steps per second of a batch of worlds (how each
  is timed: :mod:`jaxrb.bench.speed_error.measure`).

Every configuration is a plain dict; :data:`QUICK` and :data:`FULL` hold the
grids. :func:`speed_error_section` runs them and returns Markdown (one table
per scene, Pareto points marked ★, a "cheapest at each error level" line) and
writes one PNG per scene (error against cost, log-log, Pareto front joined;
:func:`jaxrb.bench.pareto.plot_speed_vs_error`).

The package's modules (use the names from ``jaxrb.bench.speed_error``; each
module imports only those listed before it):

* ``scenes``: the four scenes (tumble, bounce, slide, roll), their
  closed-form answers and the error measures against them (host NumPy);
* ``grid``: the configurations (:func:`tumble_grid`, :func:`impulse`,
  :func:`penalty`, the grids of :data:`FULL` and :data:`QUICK`), how one is
  shown (:func:`describe`, :func:`config_text`) and built (:func:`build`);
* ``measure``: running, timing and scoring one configuration
  (:class:`Point`, :func:`run_point`, :func:`time_batched`), the Pareto fronts
  and :func:`run`;
* ``section``: what the report shows (cheapest-per-level and
  best-per-cost-band lines, the Markdown tables, the plots) and
  :func:`speed_error_section`.
"""

from jaxrb.bench.speed_error.grid import (FULL, IMPULSE_STEPS, PENALTY_STEPS, QUICK, TUMBLE_CONFIGS,
                                          bounce_grid_full, build, config_text, describe, impulse,
                                          penalty, roll_grid_full, slide_grid_full, tumble_grid)
from jaxrb.bench.speed_error.measure import (BATCH_MODES, Point, batched_points, mark_fronts, run,
                                             run_point, time_batched)
from jaxrb.bench.speed_error.scenes import (DOWNHILL, DROP, GRAVITY, HALF, NUM_APEXES, RADIUS,
                                            RESTITUTION, ROLL_FRICTION, ROLL_SETTLE, SCENE_NAMES,
                                            SLIDE_FRICTION, SLIDE_SPEED, SLOPE, SLOPE_NORMAL,
                                            TUMBLE_ANGVEL, TUMBLE_INERTIA, acceleration_error,
                                            apex_error, apex_heights, bounce_scene, exact_answers,
                                            flip_time_error, hermite_crossings, roll_scene,
                                            slide_scene, stopping_distance_error, trajectory_error)
from jaxrb.bench.speed_error.section import (SCENE_TEXT, band_line, best_per_cost_band,
                                             cheapest_per_level, plot_scene, scene_markdown,
                                             scene_table, speed_error_section, summary_line)

__all__ = [
    # scenes
    "GRAVITY", "RADIUS", "HALF", "DROP", "RESTITUTION", "NUM_APEXES", "SLIDE_SPEED", "SLIDE_FRICTION",
    "SLOPE", "ROLL_FRICTION", "ROLL_SETTLE", "SCENE_NAMES", "SLOPE_NORMAL", "DOWNHILL",
    "TUMBLE_ANGVEL", "TUMBLE_INERTIA", "hermite_crossings", "flip_time_error", "apex_heights",
    "apex_error", "stopping_distance_error", "acceleration_error", "bounce_scene", "slide_scene",
    "roll_scene", "exact_answers", "trajectory_error",
    # grid
    "TUMBLE_CONFIGS", "tumble_grid", "impulse", "penalty", "IMPULSE_STEPS", "PENALTY_STEPS",
    "bounce_grid_full", "slide_grid_full", "roll_grid_full", "FULL", "QUICK", "describe",
    "config_text", "build",
    # measure
    "BATCH_MODES", "Point", "run_point", "time_batched", "batched_points", "mark_fronts", "run",
    # section
    "cheapest_per_level", "best_per_cost_band", "band_line", "summary_line", "SCENE_TEXT",
    "scene_table", "plot_scene", "scene_markdown", "speed_error_section",
]
