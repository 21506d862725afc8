"""``jaxrb fit SCENE DATA --out FITTED`` and ``jaxrb evaluate SCENE DATA``.

Both build the scene file with :func:`jaxrb.fit.fit_data.build_for_data`. A
scene with joints reads its data as joint-coordinate rows
(:func:`jaxrb.fit.joint_data.load_joint_trajectories`: a free base and its
joints, the elbow tosses' layout); a scene without, as bodies' poses.
"""

from __future__ import annotations

import json
import os
import time
from typing import Optional, Sequence

import numpy as np

from jaxrb.fit.evaluate import noise_floor, plot_scores, prepare_replay, score
from jaxrb.fit.fit_data import build_for_data, fit_measured, fitted_scene, load_for_scene
from jaxrb.fit.measured import Trajectories


def _select(trajectories: Trajectories, which: Optional[str]) -> Trajectories:
    """``which``: None (all) or ``"start:stop"`` trajectory indices."""
    if not which:
        return trajectories
    try:
        start, stop = (int(part) if part else None for part in which.split(":"))
    except ValueError:
        raise ValueError(f"--trajectories: expected START:STOP, got {which!r}") from None
    return trajectories.subset(slice(start, stop))


def load_data(path, scene_path, sample_dt: Optional[float], angvel_frame: Optional[str], which: Optional[str]):
    return _select(load_for_scene(path, scene_path, sample_dt=sample_dt, angvel_frame=angvel_frame), which)


def evaluate_command(scene_path, data_path, *, sample_dt=None, angvel_frame=None, trajectories=None,
                     plot: Optional[str] = None, floor: bool = False) -> str:
    """Score a scene file on measured data with the published protocol; returns the report text."""
    data = load_data(data_path, scene_path, sample_dt, angvel_frame, trajectories)
    _, model, params, state = build_for_data(scene_path, data)
    replay = prepare_replay(model, params, state, data)
    scores = score(replay, params)
    lines = [f"{os.fspath(scene_path)} on {os.fspath(data_path)} ({data.num_trajectories} trajectories, "
             f"tracker length scale {replay.length_scale:.4f}, median {int(np.median(replay.num_free))} "
             "free samples for the initial state)", scores.text(),
             "worst trajectories (ids): " + ", ".join(map(str, scores.worst()))]
    if floor:
        floor_scores, position_noise, rotation_noise = noise_floor(replay, params)
        lines.append(f"noise floor (tracker noise {position_noise * 1e3:.3f} mm, {np.degrees(rotation_noise):.3f}°"
                     f" re-estimated and re-simulated):\n" + floor_scores.text())
    if plot:
        plot_scores(scores, plot, title=f"{os.path.basename(os.fspath(scene_path))}: worst "
                                        + ", ".join(map(str, scores.worst())))
        lines.append(f"wrote {plot}")
    return "\n".join(lines)


def fit_command(scene_path, data_path, out, *, fields: Sequence[str], sample_dt=None, angvel_frame=None,
                trajectories=None, horizons: Sequence[int] = (8, 32), stride: int = 2, starts: int = 4,
                max_iterations: int = 20, time_budget: Optional[float] = None,
                state_path: Optional[str] = None, search_width: float = 0.2, progress=print) -> str:
    """Fit ``fields`` of a scene file to measured data and write the fitted scene file ``out``."""
    clock = time.perf_counter()
    data = load_data(data_path, scene_path, sample_dt, angvel_frame, trajectories)
    scene_file, model, params, state = build_for_data(scene_path, data)
    fit = fit_measured(model, params, state, data, fields, horizons=horizons, stride=stride, starts=starts,
                       max_iterations=max_iterations, time_budget=time_budget, progress=progress,
                       state_path=state_path, search_width=search_width)
    with open(out, "w", encoding="utf-8") as handle:
        json.dump(fitted_scene(scene_file, fit.params, fit.fields), handle, indent=1)
        handle.write("\n")
    scores = score(prepare_replay(model, fit.params, state, data, scale=fit.length_scale), fit.params)
    return "\n".join([f"fitted in {time.perf_counter() - clock:.1f} s ({fit.stages})", fit.table(),
                      "full rollouts from free-flight estimates, on the data fitted:", scores.text(),
                      f"wrote {out}"])
