"""Speed against error: the Pareto front of (cost, error) points and its plot."""

from __future__ import annotations

from typing import Optional, Sequence

import numpy as np


def pareto_front(costs: Sequence[float], errors: Sequence[float]) -> np.ndarray:
    """Which points no other point beats on both cost and error.

    Args:
        costs: (k,) cost of each configuration (lower is better), e.g. seconds per simulated second.
        errors: (k,) error of each configuration (lower is better); inf or NaN never makes the front.

    Returns:
        (k,) bools: True where no other point has cost ≤ and error ≤ with one of them strictly lower.
    """
    costs, errors = np.asarray(costs, dtype=float), np.asarray(errors, dtype=float)
    finite = np.isfinite(costs) & np.isfinite(errors)
    on_front = finite.copy()
    for i in np.nonzero(finite)[0]:
        no_worse = finite & (costs <= costs[i]) & (errors <= errors[i])
        better = (costs < costs[i]) | (errors < errors[i])
        on_front[i] = not np.any(no_worse & better)
    return on_front


def plot_speed_vs_error(ax, costs: Sequence[float], errors: Sequence[float], labels: Sequence[str],
                        groups: Sequence[str], *, xlabel: str = "cost (s per simulated s)",
                        ylabel: str = "error", title: Optional[str] = None):
    """Scatter error against cost on log axes, one colour per group, the Pareto front joined.

    Args:
        ax: matplotlib Axes to draw on.
        costs: (k,) cost of each point.
        errors: (k,) error of each point; non-finite ones are left out and counted in the legend.
        labels: (k,) short text written beside each point (e.g. the step size).
        groups: (k,) group of each point (e.g. the integrator); one colour and legend entry each.
        xlabel, ylabel, title: axis texts.

    Returns:
        ax, for chaining.
    """
    costs, errors = np.asarray(costs, dtype=float), np.asarray(errors, dtype=float)
    finite = np.isfinite(costs) & np.isfinite(errors) & (errors > 0)
    for group in dict.fromkeys(groups):
        members = np.array([g == group for g in groups]) & finite
        missing = sum(1 for g, ok in zip(groups, finite) if g == group and not ok)
        name = group if not missing else f"{group} ({missing} failed)"
        ax.scatter(costs[members], errors[members], label=name, zorder=3)
    for cost, error, label, ok in zip(costs, errors, labels, finite):
        if ok:
            ax.annotate(label, (cost, error), textcoords="offset points", xytext=(4, 3), fontsize=7)
    front = pareto_front(np.where(finite, costs, np.nan), errors)
    order = np.argsort(costs[front])
    ax.plot(costs[front][order], errors[front][order], "k--", lw=0.8, label="Pareto front", zorder=2)
    ax.set(xscale="log", yscale="log", xlabel=xlabel, ylabel=ylabel, title=title)
    label_short_log_axes(ax)
    ax.legend(fontsize=8)
    return ax


def label_short_log_axes(ax):
    """Number the log axes of ``ax`` at major ticks only: at 1, 2 and 5 a decade where an axis is short.

    Matplotlib numbers only the powers of ten on a log axis, so costs that all
    fell between 1.2e-4 and 9e-4 left the axis with no number on it; its
    minor-tick labels, shown on axes spanning about a decade, collide.
    """
    from matplotlib import ticker

    for axis, (low, high) in ((ax.xaxis, ax.get_xlim()), (ax.yaxis, ax.get_ylim())):
        axis.set_minor_formatter(ticker.NullFormatter())
        powers_inside = np.floor(np.log10(high)) - np.ceil(np.log10(low)) + 1
        if powers_inside < 2:
            axis.set_major_locator(ticker.LogLocator(base=10.0, subs=(1.0, 2.0, 5.0)))
            # (its default thresholds would label only some of 1, 2 and 5 on a short axis)
            axis.set_major_formatter(ticker.LogFormatterSciNotation(labelOnlyBase=False,
                                                                    minor_thresholds=(np.inf, np.inf)))
