"""Animations of a trajectory (real time by default), and writing them to files or HTML."""

from __future__ import annotations

import math
import pathlib
from typing import Optional

import jax
import numpy as np

from jaxrb.render.common import _check_params, _check_state, _is_positive, _new_axes
from jaxrb.render.painter import _painter
from jaxrb.model.types import Model, Params, State

SAVE_SUFFIXES = (".gif", ".mp4", ".html")


def _with_initial(model: Model, initial: State, traj: State, caller: str) -> State:
    """``traj`` with the one-world state ``initial`` put in front, as host arrays."""
    _check_state(model, initial, caller, time_axis=False)
    first, start = float(np.asarray(traj.time).reshape(-1)[0]), float(initial.time)
    if not start < first:
        raise ValueError(f"{caller}: 'initial' has time {start:g} s, not before the first state "
                         f"of 'traj' ({first:g} s); pass the state the rollout started from, or "
                         "leave 'initial' out when 'traj' already holds it")
    try:
        return jax.tree_util.tree_map(
            lambda a, b: np.concatenate([np.asarray(a)[None], np.asarray(b)]), initial, traj)
    except ValueError as error:  # fields None in one and set in the other
        raise ValueError(f"{caller}: 'initial' and 'traj' hold different State fields "
                         f"({error})") from None


def _playback(times: np.ndarray, every: int, fps, speed: float, max_fps: float):
    """(indices of the states shown, milliseconds per frame) for :func:`animate`."""
    shown = np.arange(0, len(times), every)
    if fps is not None:
        return shown, 1000.0 / fps
    steps = np.diff(times[shown])
    spacing = float(np.median(steps)) if len(steps) else math.nan
    if not (math.isfinite(spacing) and spacing > 0.0):
        return shown, 1000.0 / max_fps  # one frame, or no usable time stamps
    seconds = spacing / speed  # wall time per shown state in real time (×speed)
    # Drop frames over max_fps; the slack keeps float32 time stamps (1/60 s steps summed)
    # from dropping every second state at exactly max_fps.
    skip = max(1, math.ceil(1.0 / (max_fps * seconds) - 1e-3))
    return shown[::skip], 1000.0 * seconds * skip


def animate(model: Model, params: Params, traj: State, *, initial: Optional[State] = None,
            every: int = 1, speed: float = 1.0, max_fps: float = 30.0, fps: Optional[float] = None,
            contacts: bool = False, figsize=None, extent=None, title: Optional[str] = None,
            colors=None, view=None, dpi=None, ax=None):
    """Animate a trajectory in real time; returns a FuncAnimation, not a Figure or a file.

    The axis limits stay fixed over the whole run.

    Playback runs at the simulated pace: each shown frame lasts the simulated
    time between shown states (the median spacing of their ``time``) divided
    by ``speed``, so a 3 s rollout plays for 3 s whatever ``dt`` is. When that
    would mean more than ``max_fps`` frames per second, states are left out
    evenly (beyond ``every``) rather than time slowed: 60 Hz states play at
    30 frames per second, every second state. ``fps=`` instead fixes the
    frame rate and shows every ``every``-th state whatever the time stamps
    (playback then runs at fps·every·dt of simulated time per second).

    Poses and (if asked) contacts of every shown frame are computed once here;
    each frame of the animation only moves the artists.

    Example::

        traj = rb.rollout(step, state, params, 180)       # 3 s at 60 Hz
        anim = rb.render.animate(model, params, traj, initial=state)
        rb.render.save_animation(anim, "run.gif")         # plays for 3 s
        fig = anim.jaxrb_painter.ax.figure                # its Figure, e.g. for a still

    Args:
        model: the scene's Model.
        params: Params of one world.
        traj: State with a leading time axis, e.g. from :func:`jaxrb.rollout`:
            ``pos`` (T, n, dim), ``time`` (T,).
        initial: State of one world shown as frame 0, before ``traj``:
            :func:`jaxrb.rollout` returns the states after each step, not the
            one it started from, so pass that one here. Its ``time`` must be
            before ``traj.time[0]``. Default: start at ``traj``'s first state.
        every: show at most every ``every``-th state (1: all, subject to
            ``max_fps``); counted from frame 0 (``initial`` when given).
        speed: playback speed relative to simulated time (0.5: half speed).
        max_fps: most frames per second in real-time playback; more states
            are skipped to stay under it. GIFs keep time to 1/100 s and
            browsers slow GIF frames shorter than 0.02 s, so keep it <= 50
            for GIFs.
        fps: a fixed frame rate instead of real time (``speed`` and
            ``max_fps`` are then unused); default None (real time).
        contacts: draw the active contacts of each frame (see :func:`draw`).
        figsize: figure size in inches; default (5, 5) in 3D, (6, 4.5) in 2D.
        extent: fixed limits as in :func:`draw`; default encloses the bodies in
            every frame.
        title: title text; the time ``t = ... s`` is appended per frame.
        colors: body colours as in :func:`draw`.
        view: 3D only, (elevation, azimuth) in degrees.
        dpi: figure resolution; default matplotlib's.
        ax: Axes to animate in (its figure is used); default a new figure
            that is not registered with pyplot, so a notebook shows only the
            animation, not a stray still.

    Returns:
        A :class:`matplotlib.animation.FuncAnimation` (not a Figure and not a
        file: write it with :func:`save_animation`, which returns the path, or
        show it in a notebook with :func:`to_html`). Keep a reference to it
        until it is saved or shown. Its Figure is
        ``anim.jaxrb_painter.ax.figure``; ``anim.jaxrb_fps`` is its frame
        rate and ``anim.jaxrb_painter.set_frame(i)`` moves the figure to shown
        frame ``i`` (e.g. for a still). Long animations exceed matplotlib's
        ``animation.embed_limit`` (20 MB) as HTML; show fewer frames with
        ``every`` or ``max_fps``.

    Raises:
        ValueError: ``traj`` without a time axis or with a batch axis, an
            ``initial`` that is not one world of the model or not before
            ``traj``, ``every`` < 1, ``speed``, ``max_fps`` or ``fps`` not
            positive, ``fps`` with a ``speed`` other than 1, or a bad
            ``extent``/``colors``/``view``.
    """
    from matplotlib.animation import FuncAnimation

    caller = "animate"
    _check_state(model, traj, caller, time_axis=True)
    _check_params(model, params, caller)
    if not (isinstance(every, (int, np.integer)) and not isinstance(every, bool) and every >= 1):
        raise ValueError(f"{caller}: 'every' must be an integer >= 1, got {every!r}")
    for name, value in (("speed", speed), ("max_fps", max_fps)) + ((("fps", fps),) if fps is not None else ()):
        if not _is_positive(value):
            raise ValueError(f"{caller}: {name!r} must be a positive number, got {value!r}")
    if fps is not None and speed != 1.0:
        raise ValueError(f"{caller}: give 'fps' (a fixed frame rate) or 'speed' (real time × "
                         f"speed), not both; got fps={fps!r}, speed={speed!r}")
    if initial is not None:
        traj = _with_initial(model, initial, traj, caller)
    times = np.broadcast_to(np.asarray(traj.time, dtype=np.float64), np.shape(traj.pos)[:1])
    indices, interval = _playback(times, every, fps, float(speed), float(max_fps))
    shown = jax.tree_util.tree_map(lambda x: np.asarray(x)[indices], traj)
    if ax is None:
        if figsize is None:
            figsize = (5.0, 5.0) if model.dim == 3 else (6.0, 4.5)
        ax = _new_axes(model.dim, figsize, pyplot=False, dpi=dpi)
    painter = _painter(model, params, shown, ax, caller, contacts=contacts, colors=colors,
                       extent=extent, view=view, title=title, show_time=True)
    anim = FuncAnimation(ax.figure, painter.set_frame, frames=len(painter.frames),
                         init_func=lambda: painter.set_frame(0), interval=interval,
                         blit=False, cache_frame_data=False)
    anim.jaxrb_fps = 1000.0 / interval
    anim.jaxrb_painter = painter
    return anim


def _animation_fps(anim, fps):
    if fps is not None:
        if not _is_positive(fps):
            raise ValueError(f"save_animation: 'fps' must be a positive number, got {fps!r}")
        return float(fps)
    stored = getattr(anim, "jaxrb_fps", None)
    if stored is not None:
        return stored
    interval = getattr(anim, "_interval", None)  # matplotlib's own animations: from the interval
    return 1000.0 / interval if interval else 30.0


def _gif_writer(fps: float):
    """Pillow's GIF writer with frame durations that keep time: a GIF stores them in
    1/100 s, and one rounded duration (33 ms at 30 fps) would run 10 % fast, so frame k
    ends at (k + 1)/fps rounded to 1/100 s (30, 40, 30, 30, 40, ... ms). Durations stay
    >= 20 ms: browsers play shorter GIF frames at 100 ms."""
    from matplotlib.animation import PillowWriter

    class _TimedPillowWriter(PillowWriter):
        def finish(self):
            frames = getattr(self, "_frames", None)
            if not frames:  # matplotlib changed its writer: fall back to its own timing
                return super().finish()
            ends = np.round(np.arange(1, len(frames) + 1) * 100.0 / self.fps) * 10.0
            durations = np.maximum(np.diff(ends, prepend=0.0), 20.0)
            frames[0].save(self.outfile, save_all=True, append_images=frames[1:],
                           duration=[int(d) for d in durations], loop=0)

    return _TimedPillowWriter(fps=fps)


def save_animation(anim, path, *, fps: Optional[float] = None, dpi=None):
    """Write an animation to a file chosen by the suffix of ``path``.

    ``.gif`` uses Pillow, with frame durations rounded to the GIF's 1/100 s
    so that the total time stays right; ``.mp4`` uses ffmpeg (a ValueError when ffmpeg is not
    installed; ``.gif`` needs nothing extra); ``.html`` writes the
    self-contained HTML/JavaScript player of :func:`to_html`.

    Args:
        anim: a matplotlib animation, e.g. from :func:`animate`.
        path: file name (str or path) ending in ``.gif``, ``.mp4`` or ``.html``.
        fps: frames per second; default the animation's own
            (``anim.jaxrb_fps`` from :func:`animate`: real time unless it was
            given ``fps``).
        dpi: resolution; default the figure's.

    Returns:
        The path written, as a :class:`pathlib.Path`.

    Raises:
        ValueError: an unknown suffix (the message lists the valid ones), a
            ``.mp4`` without ffmpeg, or ``fps`` <= 0.
    """
    from matplotlib import animation

    path = pathlib.Path(path)
    suffix = path.suffix.lower()
    if suffix not in SAVE_SUFFIXES:
        raise ValueError(f"save_animation: unknown file suffix {path.suffix!r} in {str(path)!r}; "
                         f"valid suffixes are: {', '.join(SAVE_SUFFIXES)}")
    fps = _animation_fps(anim, fps)
    if suffix == ".gif":
        anim.save(path, writer=_gif_writer(fps), dpi=dpi)
    elif suffix == ".mp4":
        if not animation.writers.is_available("ffmpeg"):
            raise ValueError("save_animation: writing .mp4 needs ffmpeg, which is missing (not on "
                             "PATH); install ffmpeg or save as .gif (Pillow) or .html instead")
        anim.save(path, writer=animation.FFMpegWriter(fps=fps), dpi=dpi)
    else:
        path.write_text(anim.to_jshtml(fps=fps), encoding="utf-8")
    return path


def to_html(anim) -> str:
    """The animation as a self-contained HTML/JavaScript player, for notebooks.

    Use as ``IPython.display.HTML(rb.render.to_html(anim))``.

    Args:
        anim: a matplotlib animation, e.g. from :func:`animate`.

    Returns:
        HTML text with the frames embedded as PNG images and a ``<script>`` player.
    """
    return anim.to_jshtml(fps=_animation_fps(anim, None))
