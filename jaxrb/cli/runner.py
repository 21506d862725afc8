"""``jaxrb run SCENE_FILE``: simulate a scene file, save the trajectory, animation and a report.

The rollout is jitted once and run in segments so that long runs show
progress; the trajectory goes to ``trajectory.npz`` (arrays keyed by State
field, every ``every``-th state, the initial state first), the animation to
``animation.gif`` (or ``.mp4`` / ``.html``), and the text report to
``report.txt`` and the console.
"""

from __future__ import annotations

import math
import pathlib
import sys
import time
from typing import Callable, Optional

import jax
import numpy as np

from jaxrb import render
from jaxrb.compile import jit
from jaxrb.physics.dynamics import kinetic_energy, potential_energy
from jaxrb.files.scenefile import load_scene
from jaxrb.physics.step import make_step, rollout

#: A long run is cut into this many segments (at most), to report progress between them.
PROGRESS_LINES = 20
#: Seconds between progress lines (a short run prints only the last).
PROGRESS_SECONDS = 1.0
ANIMATION_FORMATS = ("gif", "mp4", "html", "none")


def _segments(num_steps: int, every: int) -> list:
    """Split ``num_steps`` (a multiple of ``every``) into at most PROGRESS_LINES + 1 segment lengths.

    All but possibly the last have the same length, so the rollout compiles at most twice.
    """
    saved = num_steps // every
    per_segment = every * max(1, math.ceil(saved / PROGRESS_LINES))
    full, rest = divmod(num_steps, per_segment)
    return [per_segment] * full + ([rest] if rest else [])


def simulate(step: Callable, state, params, num_steps: int, every: int = 1,
             progress: Optional[Callable[[str], None]] = None):
    """Roll ``step`` out for ``num_steps`` in segments, reporting progress after each.

    Args:
        step: from :func:`jaxrb.make_step`.
        state: initial State of one world.
        params: Params.
        num_steps: steps to take, a positive multiple of ``every``.
        every: keep every ``every``-th state.
        progress: called with a line of text after a segment when a second has
            passed since the last line, and at the end (None: silent).

    Returns:
        State with a leading time axis of length num_steps // every + 1 (the
        initial state first), as NumPy arrays.
    """
    if num_steps < 1 or every < 1 or num_steps % every:
        raise ValueError(f"run: --steps ({num_steps}) must be a positive multiple of --every ({every})")
    compiled = {}
    pieces = [jax.tree_util.tree_map(lambda a: np.asarray(a)[None], state)]
    done, start = 0, time.perf_counter()
    last_line = start
    for length in _segments(num_steps, every):
        if length not in compiled:
            compiled[length] = jit(lambda s, p, n=length: rollout(step, s, p, n, every=every))
        segment = jax.block_until_ready(compiled[length](state, params))
        state = jax.tree_util.tree_map(lambda a: a[-1], segment)
        pieces.append(jax.tree_util.tree_map(np.asarray, segment))
        done += length
        now = time.perf_counter()
        if progress is not None and (now - last_line >= PROGRESS_SECONDS or done == num_steps):
            last_line, elapsed = now, now - start
            progress(f"  {done:>{len(str(num_steps))}d}/{num_steps} steps "
                     f"({100 * done / num_steps:3.0f} %), {elapsed:.1f} s")
    return jax.tree_util.tree_map(lambda *arrays: np.concatenate(arrays), *pieces)


def run_scene_file(path, num_steps: int, out_dir, *, every: int = 1, animation: str = "gif",
                   frames: int = 150, progress: Optional[Callable[[str], None]] = None) -> str:
    """Simulate a scene file and write ``trajectory.npz``, an animation and ``report.txt``.

    Args:
        path: a ``.json`` jaxrb scene (see :mod:`jaxrb.files.scenefile`) or an MJCF ``.xml``
            (see :mod:`jaxrb.files.mjcf`).
        num_steps: steps to simulate (a multiple of ``every``).
        out_dir: output folder, created if needed.
        every: keep every ``every``-th state in the trajectory.
        animation: one of ``"gif"``, ``"mp4"`` (needs ffmpeg), ``"html"``, ``"none"``.
        frames: at most this many animation frames (states are skipped evenly);
            it plays in real time, at up to 50 frames per second (the most a
            GIF shows at full pace).
        progress: called with progress lines (None: silent).

    Returns:
        The report text (also written to ``out_dir/report.txt``).
    """
    if animation not in ANIMATION_FORMATS:
        raise ValueError(f"run: unknown animation {animation!r}; valid: {', '.join(ANIMATION_FORMATS)}")
    scene_file = load_scene(path)
    model, params, state = scene_file.build()
    out_dir = pathlib.Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    traj = simulate(make_step(model), state, params, num_steps, every, progress)
    elapsed = time.perf_counter() - start
    np.savez(out_dir / "trajectory.npz", **{name: getattr(traj, name) for name in traj.__dataclass_fields__
                                            if getattr(traj, name) is not None})

    energy = np.asarray(jax.vmap(lambda s: kinetic_energy(model, params, s).sum()
                                 + potential_energy(model, params, s).sum())(traj))
    finite = all(np.all(np.isfinite(leaf)) for leaf in jax.tree_util.tree_leaves(traj))
    lines = [f"jaxrb run {path}", model.summary(),
             f"{num_steps} steps of {float(params.dt):g} s ({num_steps * float(params.dt):g} s simulated) "
             f"in {elapsed:.2f} s wall incl. compile",
             f"energy: {energy[0]:.6g} J at start, {energy[-1]:.6g} J at end",
             "state finite throughout" if finite else "NON-FINITE values in the state (NaN/inf)"]
    lines += [f"warning: {warning}" for warning in scene_file.warnings]
    lines.append("final centre-of-mass positions (m):")
    lines += [f"  body {i}: " + " ".join(f"{x:+.5f}" for x in row) for i, row in enumerate(traj.pos[-1])]
    written = ["trajectory.npz", "report.txt"]
    if animation != "none":
        stride = max(1, math.ceil(len(traj.time) / frames))
        # ``frames`` already bounds the work; 50 fps is the fastest a GIF plays in a browser.
        movie = render.animate(model, params, jax.tree_util.tree_map(lambda a: a[::stride], traj),
                               title=pathlib.Path(path).name, max_fps=50)
        render.save_animation(movie, out_dir / f"animation.{animation}")
        written.append(f"animation.{animation}")
    lines.append("wrote " + ", ".join(str(out_dir / name) for name in written))
    report = "\n".join(lines)
    (out_dir / "report.txt").write_text(report + "\n")
    return report


def print_progress(line: str) -> None:
    """Print a progress line to stderr, so that stdout holds only the report.

    Args:
        line: the text of one progress line.
    """
    print(line, file=sys.stderr, flush=True)
