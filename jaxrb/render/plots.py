"""Plots over time: energy, angular momentum, any series."""

from __future__ import annotations

from typing import Optional, Sequence

import jax
import numpy as np

from jaxrb.physics.dynamics import kinetic_energy, potential_energy, total_angular_momentum
from jaxrb.render.common import _check_params, _check_state, _new_axes
from jaxrb.model.types import Model, Params, State


def _time_axes(ax, caller):
    if ax is None:
        return _new_axes(None)
    if getattr(ax, "name", None) == "3d":
        raise ValueError(f"{caller}: 'ax' must be a 2D Axes")
    return ax


def _per_time(model: Model, params: Params, traj: State, function):
    """``function(model, params, state)`` for every state of ``traj``, as a host array."""
    return np.asarray(jax.vmap(lambda state: function(model, params, state))(traj))


def plot_energy(model: Model, params: Params, traj: State, ax=None):
    """Plot kinetic, potential and total energy of the whole scene over time.

    Energies are summed over bodies: kinetic from :func:`jaxrb.kinetic_energy`
    (translational plus rotational), potential from
    :func:`jaxrb.potential_energy` (−m g·x, zero at the origin).

    Args:
        model: the scene's Model.
        params: Params of one world.
        traj: State with a leading time axis: ``pos`` (T, n, dim), ``time`` (T,).
        ax: 2D Axes to plot into; default a new pyplot figure.

    Returns:
        The Axes (its Figure is ``ax.figure``), with lines labelled "kinetic",
        "potential" and "total" (in J).
    """
    caller = "plot_energy"
    _check_state(model, traj, caller, time_axis=True)
    _check_params(model, params, caller)
    ax = _time_axes(ax, caller)
    kinetic = _per_time(model, params, traj, lambda m, p, s: kinetic_energy(m, p, s).sum())
    potential = _per_time(model, params, traj, lambda m, p, s: potential_energy(m, p, s).sum())
    times = np.asarray(traj.time)
    ax.plot(times, kinetic, label="kinetic")
    ax.plot(times, potential, label="potential")
    ax.plot(times, kinetic + potential, label="total", color="k", lw=1.5)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("energy (J)")
    ax.legend()
    return ax


def plot_angular_momentum(model: Model, params: Params, traj: State, ax=None):
    """Plot the total angular momentum about the world origin over time.

    3D: the components L_x, L_y, L_z and the magnitude |L|; 2D: the scalar L_z.
    Values come from :func:`jaxrb.total_angular_momentum` (spin plus orbital).

    Args:
        model: the scene's Model.
        params: Params of one world.
        traj: State with a leading time axis: ``pos`` (T, n, dim), ``time`` (T,).
        ax: 2D Axes to plot into; default a new pyplot figure.

    Returns:
        The Axes (its Figure is ``ax.figure``), lines labelled "L_x", "L_y",
        "L_z", "|L|" (3D) or "L_z" (2D).
    """
    caller = "plot_angular_momentum"
    _check_state(model, traj, caller, time_axis=True)
    _check_params(model, params, caller)
    ax = _time_axes(ax, caller)
    momentum = _per_time(model, params, traj, total_angular_momentum)
    times = np.asarray(traj.time)
    if model.dim == 3:
        for axis, name in enumerate(("L_x", "L_y", "L_z")):
            ax.plot(times, momentum[:, axis], label=name)
        ax.plot(times, np.linalg.norm(momentum, axis=1), label="|L|", color="k", lw=1.5)
    else:
        ax.plot(times, momentum, label="L_z")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("angular momentum (kg m²/s)")
    ax.legend()
    return ax


def plot_series(times, values, *, labels: Optional[Sequence[str]] = None, ax=None,
                ylabel: Optional[str] = None):
    """Plot any quantity over time, one line per component.

    Example: ``plot_series(traj.time, traj.angvel[:, 0], labels=["ωx", "ωy", "ωz"])``.

    Args:
        times: (T,) times.
        values: (T,) or (T, ...) values; trailing axes are flattened into
            one line each.
        labels: one label per line; default none (no legend).
        ax: 2D Axes to plot into; default a new pyplot figure.
        ylabel: y-axis label.

    Returns:
        The Axes (its Figure is ``ax.figure``).

    Raises:
        ValueError: ``times`` not one-dimensional, ``values`` of another
            length, or the wrong number of ``labels``.
    """
    caller = "plot_series"
    times = np.asarray(times)
    values = np.asarray(values)
    if times.ndim != 1:
        raise ValueError(f"{caller}: 'times' must have shape (T,), got {times.shape}")
    if values.ndim == 0 or values.shape[0] != times.shape[0]:
        raise ValueError(f"{caller}: 'values' must have shape (T, ...) with T = {times.shape[0]} "
                         f"as 'times', got {values.shape}")
    values = values.reshape(values.shape[0], -1)
    if labels is not None:
        labels = list(labels)
        if len(labels) != values.shape[1]:
            raise ValueError(f"{caller}: 'labels' has {len(labels)} entries but 'values' has "
                             f"{values.shape[1]} lines")
    ax = _time_axes(ax, caller)
    for column in range(values.shape[1]):
        ax.plot(times, values[:, column], label=None if labels is None else labels[column])
    ax.set_xlabel("time (s)")
    if ylabel is not None:
        ax.set_ylabel(ylabel)
    if labels is not None:
        ax.legend()
    return ax
