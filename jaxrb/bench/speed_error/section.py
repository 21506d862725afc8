"""What the speed-against-error section shows, and the section itself.

From the measured points (:mod:`jaxrb.bench.speed_error.measure`): the
cheapest configuration at each decade of error and the best error in each
decade of cost (the lines under each table), one Markdown table per scene
with the Pareto points marked ★, one PNG per scene (error against cost,
log-log, Pareto front joined), and :func:`speed_error_section`, which runs
the grid and puts them together.
"""

from __future__ import annotations

import math
import os
from typing import Callable, Optional, Sequence

from jaxrb.bench.pareto import plot_speed_vs_error
from jaxrb.bench.report import fmt_fixed, fmt_sci, fmt_si, fmt_step, markdown_table
from jaxrb.bench.speed_error.grid import config_text
from jaxrb.bench.speed_error.measure import Point, _check_settings, run
from jaxrb.bench.timing import Stopwatch

def cheapest_per_level(points: Sequence[Point]) -> list:
    """The cheapest point reaching each decade of error, from the worst finite error down.

    Args:
        points: (k,) list of :class:`Point` of one panel.

    Returns:
        [(level, point)] for levels 10^k from above the largest finite error
        down to the smallest error reached; ``point`` is the cheapest with
        error ≤ level (always on the Pareto front).
    """
    finite = [p for p in points if math.isfinite(p.error) and math.isfinite(p.cost)]
    positive = [p.error for p in finite if p.error > 0]
    if not positive:
        return []
    top = math.ceil(math.log10(max(positive)))
    bottom = math.floor(math.log10(min(positive)))
    levels = []
    for exponent in range(top, bottom - 1, -1):
        level = 10.0 ** exponent
        reaching = [p for p in finite if p.error <= level]
        if reaching:
            best = min(reaching, key=lambda p: (p.cost, p.error))
            if not levels or best is not levels[-1][1]:
                levels.append((level, best))
    return levels


def best_per_cost_band(points: Sequence[Point]) -> list:
    """The most accurate point within each decade of cost.

    Args:
        points: (k,) list of :class:`Point` of one panel.

    Returns:
        [(low, point)] for each decade [low, 10·low) of s / sim s that holds a
        point with a finite error, cheapest decade first; ``point`` has the
        smallest error in that decade (ties: the cheaper).
    """
    finite = [p for p in points if math.isfinite(p.error) and math.isfinite(p.cost) and p.cost > 0]
    bands = {}
    for point in finite:
        low = 10.0 ** math.floor(math.log10(point.cost))
        best = bands.get(low)
        if best is None or (point.error, point.cost) < (best.error, best.cost):
            bands[low] = point
    return sorted(bands.items())


def band_line(points: Sequence[Point], unit: str) -> str:
    """One line: the best error in each decade of cost.

    Args:
        points: (k,) list of :class:`Point` of one panel.
        unit: text after each error (e.g. ``" s"``).

    Returns:
        The line, or ``""`` when no point has a finite error.
    """
    bands = best_per_cost_band(points)
    if not bands:
        return ""
    parts = [f"[{fmt_sci(low, 0)}, {fmt_sci(10 * low, 0)}) s/s: {fmt_sci(p.error)}{unit} "
             f"({p.group} {p.label})" for low, p in bands]
    return "Best error per cost decade — " + "; ".join(parts) + "."


def summary_line(points: Sequence[Point], unit: str) -> str:
    """One line: the cheapest configuration at each error level.

    Args:
        points: (k,) list of :class:`Point` of one panel.
        unit: text after each level (e.g. ``" s"``).

    Returns:
        The line.
    """
    levels = cheapest_per_level(points)
    if not levels:
        return "No configuration reached a finite error."
    parts = [f"≤ {fmt_sci(level, 0)}{unit}: {p.group} {p.label} (error {fmt_sci(p.error)}, "
             f"{fmt_sci(p.cost)} s/s)"
             for level, p in levels]
    return "Cheapest at each error level — " + "; ".join(parts) + "."


SCENE_TEXT = {
    "tumble": ("Torque-free tumbling (intermediate-axis flip)", "max flip-time error", " s",
               "Body with principal inertia (0.3, 0.35, 0.4) kg m², ω₀ = (0.1, 15, 0.1) rad/s "
               "(body frame), no gravity. Error: max |t_flip − t_exact| over the flips of "
               "`analytic.flip_times` (Jacobi elliptic solution) in the horizon, flips located by "
               "cubic Hermite interpolation of the body-frame ω_y (slope from Euler's equation); "
               "inf when a flip is missing. One Pareto front per dtype."),
    "bounce": ("Bouncing sphere (restitution 0.8)", "max rel. error of 3 apexes", "",
               "Sphere r = 0.1 m, 1 kg, dropped from 1 m onto a plane, e = 0.8, semi-implicit "
               "Euler. Error: max relative error of the first three apex heights (read as "
               "z + v_z²/2g at the last rising sample) against `analytic.bounce_apexes`."),
    "slide": ("Sliding box (μ = 0.5, v₀ = 2 m/s)", "rel. error of stopping distance", "",
              "Box half 0.1 m, 1 kg, on a plane, μ = 0.5, v₀ = 2 m/s. Error: relative error of the "
              "displacement at the end of the horizon against `analytic.slide_distance` "
              "(v₀²/2μg)."),
    "roll": ("Sphere rolling down a 30° slope", "rel. error of acceleration", "",
             "Sphere r = 0.1 m, 1 kg, released at rest on a plane with a 30° tilted normal, μ = 1. "
             "Error: relative error of the downhill acceleration (quadratic fit over t ≥ 0.2 s) "
             "against `analytic.rolling_acceleration` (5/7·g·sin θ)."),
}


def scene_table(points: Sequence[Point]) -> str:
    """Markdown table of one scene's points, Pareto points marked ★.

    Args:
        points: (k,) list of :class:`Point` of one scene, fronts marked.

    Returns:
        The table.
    """
    rows = []
    for p in points:
        rows.append([
            "★" if p.on_front else "", p.group, p.label, config_text(p.scene, p.config),
            fmt_step(p.config["dt"]), fmt_sci(p.error), fmt_sci(p.cost), fmt_fixed(p.step_us, 2),
            fmt_fixed(p.compile_s, 2), fmt_si(p.body_steps_per_s) if p.batch else "—",
            fmt_fixed(p.batch_compile_s, 2) if p.batch else "—"])
    return markdown_table(
        ["★", "group", "label", "configuration", "dt (s)", "error", "s / sim s (b1)", "µs/step (b1)",
         "compile b1 (s)", "body-steps/s (batch)", "compile batch (s)"],
        rows, align=["c", "l", "l", "l", "r", "r", "r", "r", "r", "r", "r"])


def plot_scene(points: Sequence[Point], path: str) -> str:
    """PNG of error against cost, log-log, one panel per dtype (tumbling) or one panel.

    Args:
        points: (k,) list of :class:`Point` of one scene, fronts marked.
        path: file to write.

    Returns:
        ``path``.
    """
    from matplotlib.figure import Figure

    scene = points[0].scene
    title, error_name, unit, _ = SCENE_TEXT[scene]
    panels = list(dict.fromkeys(p.panel for p in points))
    figure = Figure(figsize=(6.4 * len(panels), 4.8))
    for index, panel in enumerate(panels):
        members = [p for p in points if p.panel == panel]
        axis = figure.add_subplot(1, len(panels), index + 1)
        plot_speed_vs_error(axis, [p.cost for p in members], [p.error for p in members],
                            [p.label for p in members], [p.group for p in members],
                            xlabel="wall s per simulated s (batch 1)",
                            ylabel=f"{error_name}{' (' + unit.strip() + ')' if unit else ''}",
                            title=title + ("" if panel == "all" else f" — {panel}"))
        axis.grid(True, which="both", alpha=0.3)
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    return path


def scene_markdown(scene: str, points: Sequence[Point], image: Optional[str] = None) -> str:
    """Heading, description, table, optional image link and summary lines of one scene.

    Args:
        scene: one of :data:`SCENE_NAMES`.
        points: (k,) list of :class:`Point` of that scene, fronts marked.
        image: optional file name of its PNG, linked relative to the report.

    Returns:
        The Markdown block.
    """
    title, error_name, unit, description = SCENE_TEXT[scene]
    horizon = points[0].horizon
    lines = [f"### {title}", "", description + f" Horizon {horizon:g} s.", "",
             f"*error* = {error_name}{unit and ' (' + unit.strip() + ')'}.", "",
             scene_table(points), ""]
    if image:
        lines += [f"![{title}: error against cost]({image})", ""]
    panels = list(dict.fromkeys(p.panel for p in points))
    for panel in panels:
        members = [p for p in points if p.panel == panel]
        prefix = "" if panel == "all" else f"{panel}: "
        lines.append(prefix + summary_line(members, unit))
        lines.append("")
        lines.append(prefix + band_line(members, unit))
        lines.append("")
    return "\n".join(lines).rstrip()


def speed_error_section(settings: dict, log: Optional[Callable] = None):
    """Run the speed-against-error benchmark; return ``(markdown, results)``.

    Args:
        settings: ``speed_error_*`` keys as in :data:`QUICK` / :data:`FULL`
            (missing ones from :data:`QUICK`); ``out_dir`` (or
            ``speed_error_out_dir``): where the PNGs go (none written without
            it); ``repeats`` when ``speed_error_repeats`` is absent.
        log: optional progress callback taking one string.

    Returns:
        ``(markdown, results)``: the section text (one subsection per scene)
        and ``{"scenes": {scene: list of Point}, "images": {scene: PNG path},
        "seconds": wall time of the runs}``.
    """
    merged = _check_settings(settings)
    with Stopwatch() as watch:
        results = run(merged, log)
    out_dir = merged.get("speed_error_out_dir")
    images = {}
    batch_mode = merged["speed_error_batch_configs"]
    batch_text = {"all": "every configuration",
                  "pareto": "the Pareto-front configurations only (to save time)",
                  "cheapest": "the cheapest Pareto-front configuration of each front only "
                              "(to save time)",
                  "none": "no configuration"}[batch_mode]
    parts = [
        "Error against the closed form against cost, for the configurations the engine "
        "offers. *s / sim s (b1)*: median wall time (compile excluded, block_until_ready, up to "
        f"{merged['speed_error_repeats']} calls after a warm-up) of the jitted batch-1 rollout "
        "over the horizon, all states stacked, per simulated second; *compile b1*: trace + lower + "
        f"compile of it. *body-steps/s (batch)*: `jax.vmap` over {merged['speed_error_batch']} "
        f"worlds (each lifted 0–1 mm, spin nudged ≤ 1e-3 rad/s) of a {merged['speed_error_batch_steps']}"
        f"-step rollout in one jit (final state only), measured for {batch_text}; a step includes "
        "its substeps. Contact scenes run in float32. ★: on the Pareto front (no other "
        "configuration is both cheaper and more accurate); cheapest-at-each-level lines read the "
        "front. Timings were taken on a shared machine and are noisy; errors are not.",
    ]
    for scene, points in results.items():
        image = None
        if out_dir:
            os.makedirs(out_dir, exist_ok=True)
            path = plot_scene(points, os.path.join(out_dir, f"speed_error_{scene}.png"))
            images[scene] = path
            image = os.path.basename(path)
        parts.append(scene_markdown(scene, points, image))
    parts.append(f"Speed-against-error wall time: {watch.seconds:.1f} s.")
    return "\n\n".join(parts), {"scenes": results, "images": images, "seconds": watch.seconds}
