"""jaxrb's rows of the peers' scenes (:mod:`benchmarks.scenes`), at the settings each row names.

The box drop (:func:`jaxrb_drop`), the 10-box column (:func:`jaxrb_stack`),
the 55-box 2D pyramid (:func:`jaxrb_pyramid`) and the torque-free flip
(:func:`jaxrb_flip`), in float32 (the flip also in float64), batched with
``jax.vmap`` over worlds shifted by :func:`benchmarks.scenes.world_shifts`.
Each returns a :class:`benchmarks.scenes.PeerRow` like the peers' runs
(:mod:`benchmarks.peer_runs`). :mod:`benchmarks.accelerator` times the same
functions at GPU-sized batches.
"""

from __future__ import annotations

from typing import Callable, Optional

import jax
import jax.numpy as jnp
import numpy as np

from benchmarks.scenes import (LOOP_SUFFIX, PYRAMID_ROWS, PYRAMID_TOP, STACK_COUNT, STACK_TOP_REST,
                               STANDING_SETTINGS, PeerRow, pyramid_centres, rest_metrics, stack_metrics, time_jax,
                               x64)
from jaxrb.bench import contact, free_body
from jaxrb.bench.report import fmt_step
from jaxrb.bench.timing import final_state_fn
from jaxrb.model.options import grouped


def _user_loop(step: Callable, num_steps: int, batched: bool) -> Callable:
    """``(state, params) -> state``: a ``fori_loop`` over ``vmap(step)``, the loop a user writes by hand."""
    advance = jax.vmap(step, in_axes=(0, None)) if batched else step
    return lambda state, params: jax.lax.fori_loop(0, num_steps, lambda _, s: advance(s, params), state)


def _jaxrb_batched(scene_factory, dt, substeps, batch, num_steps, settings, build=None, form="rollout"):
    import jaxrb as rb

    options = {"contact": "impulse", "substeps": substeps, **(build or {})}
    model, params, state = scene_factory().build(**grouped(dict(options, dtype=jnp.float32, dt=dt)))
    step = rb.make_step(model)
    if batch > 1:
        state = contact._batched_state(state, batch)
    run = (final_state_fn if form == "rollout" else _user_loop)(step, num_steps, batch > 1)
    timing = time_jax(run, state, params, settings=settings)
    initial = np.asarray(state.pos, dtype=np.float64).reshape((batch,) + tuple(state.pos.shape[-2:]))
    final = np.asarray(timing.output.pos, dtype=np.float64).reshape(initial.shape)
    return timing, initial, final, int(state.pos.shape[-2])


def _setting_text(dt: float, substeps: int, build=None) -> str:
    build = build or {}
    substeps = build.get("substeps", substeps)
    text = f"{build.get('contact', 'impulse')}, {fmt_step(dt)} s" + (f" × {substeps}" if substeps > 1 else "")
    if "penalty_frequency" in build:
        text += f", spring {build['penalty_frequency']:.3g} Hz"
    if "broadphase" in build:
        text += f", {build['broadphase']} broadphase ({build['broadphase_capacity']} pairs)"
    return text


def jaxrb_drop(contact_model: str, dt: float, substeps: int, batch: int, num_steps: int,
               settings: dict, form: str = "rollout") -> PeerRow:
    """jaxrb's box drop with ``contact_model`` at step ``dt`` with ``substeps``; see the module docstring.

    ``form``: ``"rollout"`` (``vmap`` of ``rb.rollout``) or ``"loop"`` (a
    ``fori_loop`` over ``vmap(step)``, as a user writes it); the same step.

    Args:
        contact_model: ``"impulse"`` or ``"penalty"`` (its default stiffness and damping).
        dt: step (s).
        substeps: substeps per step.
        batch: worlds.
        num_steps: steps per call.
        settings: section settings (``peers_repeats``, ``peers_budget_s``).

    Returns:
        A :class:`PeerRow` with ``rest_offset`` and ``rest_error`` metrics.
    """
    build = {"contact": contact_model}
    timing, _, final, bodies = _jaxrb_batched(contact.drop_scene, dt, substeps, batch, num_steps,
                                              settings, build, form)
    setting = _setting_text(dt, substeps, build) + (LOOP_SUFFIX if form == "loop" else "")
    return PeerRow("drop", "jaxrb", setting, dt, batch, bodies, num_steps,
                   timing.compile_s, timing.run_s, rest_metrics(final[:, 0, 2]))


def _jaxrb_standing(scene: str, make_scene, top: int, rest_height: float, contact_model: str, batch: int,
                    seconds: float, settings: dict) -> PeerRow:
    """jaxrb with ``contact_model`` (:data:`STANDING_SETTINGS`) for ``seconds``; sink and drift of body ``top``."""
    if contact_model not in STANDING_SETTINGS:
        raise ValueError(f"peers: unknown jaxrb contact model {contact_model!r} for the {scene}; valid: "
                         f"{', '.join(STANDING_SETTINGS)}")
    dt, substeps, build = STANDING_SETTINGS[contact_model][scene]
    num_steps = max(1, int(round(seconds / dt)))
    timing, initial, final, bodies = _jaxrb_batched(make_scene, dt, substeps, batch, num_steps, settings,
                                                    build)
    metrics = stack_metrics(initial[:, top], final[:, top], rest_height)
    # A broadphase that ran out of pairs drops contacts: such a run does not count as standing.
    metrics["overflow"] = bool(np.any(np.asarray(timing.output.overflow)))
    metrics["stands"] = metrics["stands"] and not metrics["overflow"]
    return PeerRow(scene, "jaxrb", _setting_text(dt, substeps, build), dt, batch, bodies, num_steps,
                   timing.compile_s, timing.run_s, metrics)


def jaxrb_stack(contact_model: str, batch: int, seconds: float, settings: dict) -> PeerRow:
    """jaxrb's 10-box column with ``contact_model`` for ``seconds``; sink and drift of the top box."""
    return _jaxrb_standing("stack", lambda: contact.stack3d_scene(STACK_COUNT), -1, STACK_TOP_REST,
                           contact_model, batch, seconds, settings)


def jaxrb_pyramid(contact_model: str, batch: int, seconds: float, settings: dict) -> PeerRow:
    """jaxrb's 55-box 2D pyramid with ``contact_model`` for ``seconds``; does it stand."""
    return _jaxrb_standing("pyramid", lambda: contact.pyramid2d_scene(PYRAMID_ROWS), PYRAMID_TOP,
                           pyramid_centres()[PYRAMID_TOP][1], contact_model, batch, seconds, settings)


def jaxrb_flip(integrator: str, orientation: Optional[str], h: float, t_end: float, dtype,
               reference: np.ndarray, settings: dict) -> PeerRow:
    """jaxrb's torque-free flip (:func:`jaxrb.bench.free_body.run_tumble`) against ``reference``."""
    with x64(True):  # float64 runs need it; float32 runs ask for their dtype explicitly
        result = free_body.run_tumble(integrator, orientation, h, t_end, dtype, reference,
                                      repeats=settings["peers_repeats"])
    name = integrator + (f"/{orientation}" if orientation else "")
    return PeerRow("flip", "jaxrb", name, h, 1, 1, result.num_steps, result.compile_s, result.run_s,
                   {"flip_error": result.flips.max_error, "flips": result.flips.count_text,
                    "dtype": result.dtype})
