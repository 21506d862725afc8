"""The configurations of the speed-against-error section, and how each is shown and built.

A configuration is a plain dict of build options and its dtype:
:func:`tumble_grid` (integrator and orientation update × step × dtype, for the
tumbling scene), :func:`impulse` and :func:`penalty` (one contact
configuration each). The grids of the committed report (:data:`FULL`) and of
``--quick`` (:data:`QUICK`) are here; :func:`describe` and
:func:`config_text` say how a configuration is shown, and :func:`build`
builds a scene under one.
"""

from __future__ import annotations

from typing import Sequence

import jax.numpy as jnp

from jaxrb.bench.free_body import TUMBLE_CONFIGS, tumble_scene
from jaxrb.bench.report import fmt_step
from jaxrb.bench.speed_error.scenes import SCENE_NAMES, bounce_scene, roll_scene, slide_scene
from jaxrb.model.options import grouped


# --- configuration grids --------------------------------------------------------------------

def tumble_grid(steps: Sequence[float], dtypes: Sequence[str] = ("float64", "float32"),
                configs: Sequence[tuple] = TUMBLE_CONFIGS) -> list:
    """Every (integrator, orientation) pair × step × dtype, as configuration dicts.

    Args:
        steps: (s,) step sizes (s).
        dtypes: dtype names.
        configs: (integrator, orientation or None) pairs; default all seven.

    Returns:
        A list of dicts with keys integrator, orientation, dt, dtype.
    """
    return [dict(integrator=integrator, orientation=orientation, dt=float(h), dtype=dtype)
            for dtype in dtypes for integrator, orientation in configs for h in steps]


def impulse(dt, substeps=4, iterations=4, time_of_impact=False, solver="sequential",
            integrator="semi_implicit", dtype="float32") -> dict:
    """One impulse-contact configuration.

    Args:
        dt: scalar step of one ``step`` call (s).
        substeps: substeps per step.
        iterations: impulse iterations per substep.
        time_of_impact: resolve sphere–plane impacts at their time inside the substep.
        solver: ``"sequential"`` or ``"jacobi"``.
        integrator: ``"semi_implicit"`` or ``"implicit_gyro"``.
        dtype: dtype name.

    Returns:
        The configuration dict (the build options it sets, and its dtype).
    """
    return dict(contact="impulse", dt=float(dt), substeps=substeps, iterations=iterations,
                time_of_impact=time_of_impact, solver=solver, integrator=integrator, dtype=dtype)


def penalty(dt, friction="spring", smooth=False, integrator="semi_implicit",
            dtype="float32") -> dict:
    """One penalty-contact configuration (one substep; the default spring of 0.03/h Hz).

    Args:
        dt: scalar step (s).
        friction: penalty friction law, ``"spring"`` or ``"regularized"``.
        smooth: use the softplus activation (width 1 mm).
        integrator: ``"semi_implicit"`` or ``"implicit_gyro"``.
        dtype: dtype name.

    Returns:
        The configuration dict.
    """
    return dict(contact="penalty", dt=float(dt), substeps=1, penalty_friction=friction,
                smooth=smooth, integrator=integrator, dtype=dtype)


IMPULSE_STEPS = (1 / 60, 1 / 120, 1 / 240)
PENALTY_STEPS = (2e-3, 1e-3, 5e-4)


def bounce_grid_full() -> list:
    """Bounce: dt × substeps (1, 2, 4, 8); time of impact at substeps 1 and 4; iterations 2
    and 8 and the Jacobi solver at one setting; penalty at three steps and with the smooth
    activation. Iterations barely matter for one sphere, so they are not crossed with the rest.

    Returns:
        A list of configuration dicts.
    """
    grid = [impulse(dt, substeps) for substeps in (1, 2, 4, 8) for dt in IMPULSE_STEPS]
    grid += [impulse(dt, substeps, time_of_impact=True) for substeps in (1, 4) for dt in IMPULSE_STEPS]
    grid += [impulse(1 / 120, 4, iterations=2), impulse(1 / 120, 4, iterations=8),
             impulse(1 / 120, 4, solver="jacobi")]
    grid += [penalty(dt) for dt in PENALTY_STEPS] + [penalty(1e-3, smooth=True)]
    return grid


def slide_grid_full() -> list:
    """Slide: impulse dt × substeps (1, 4) plus iterations 2/8 and Jacobi at 1/60 × 4;
    penalty at three steps with the spring friction law and one with the regularised law.

    Returns:
        A list of configuration dicts.
    """
    grid = [impulse(dt, substeps) for substeps in (1, 4) for dt in IMPULSE_STEPS]
    grid += [impulse(1 / 60, 4, iterations=2), impulse(1 / 60, 4, iterations=8),
             impulse(1 / 60, 4, solver="jacobi"), impulse(1 / 60, 4, time_of_impact=True)]
    grid += [penalty(dt) for dt in PENALTY_STEPS] + [penalty(1e-3, friction="regularized")]
    return grid


def roll_grid_full() -> list:
    """Roll: impulse dt × substeps (1, 4), iterations 2, Jacobi and the implicit gyroscopic
    integrator at 1/60 × 4; penalty at three steps and with the regularised friction law.

    Returns:
        A list of configuration dicts.
    """
    grid = [impulse(dt, substeps) for substeps in (1, 4) for dt in IMPULSE_STEPS]
    grid += [impulse(1 / 60, 4, iterations=2), impulse(1 / 60, 4, solver="jacobi"),
             impulse(1 / 60, 4, integrator="implicit_gyro")]
    grid += [penalty(dt) for dt in PENALTY_STEPS] + [penalty(1e-3, friction="regularized")]
    return grid


#: Settings of the committed report: the grids above, 1 024 worlds.
FULL = dict(
    speed_error_scenes=SCENE_NAMES,
    speed_error_configs={
        "tumble": tumble_grid((1 / 60, 1 / 120, 1 / 240, 1 / 480, 1 / 1000)),
        "bounce": bounce_grid_full(),
        "slide": slide_grid_full(),
        "roll": roll_grid_full(),
    },
    speed_error_horizons={"tumble": 20.0, "bounce": 2.2, "slide": 0.8, "roll": 1.0},
    speed_error_batch=1024, speed_error_batch_steps=100, speed_error_batch_configs="all",
    speed_error_repeats=5,
)

#: A run of about 25 s on 2 cores: one configuration a scene (the flip's is the
#: float32 target's integrator; the peers section runs it in float64 too) and its
#: batched throughput. Compiles dominate the time, and impulse contact's most (the
#: bounce's compiled for 11 s, the roll's for 13 s at batch 1 and 1 024), so quick's
#: contact scenes run penalty contact only; the contact section shows impulse
#: contact's cost.
QUICK = dict(
    speed_error_scenes=SCENE_NAMES,
    speed_error_configs={
        "tumble": tumble_grid((1 / 60,), ("float32",), (("rk4_body", None),)),
        "bounce": [penalty(1e-3)],
        "slide": [penalty(2e-3)],
        "roll": [penalty(2e-3)],
    },
    speed_error_horizons={"tumble": 5.0, "bounce": 2.2, "slide": 0.6, "roll": 0.6},
    speed_error_batch=1024, speed_error_batch_steps=50, speed_error_batch_configs="cheapest",
    speed_error_repeats=3,
)


# --- showing and building one configuration ------------------------------------------------

def describe(scene: str, config: dict) -> tuple:
    """How a configuration is shown.

    Args:
        scene: one of :data:`SCENE_NAMES`.
        config: a configuration dict.

    Returns:
        ``(group, label, panel)``: legend group, text beside the point, plot panel.
    """
    if scene == "tumble":
        group = config["integrator"] + (f"/{config['orientation']}" if config["orientation"] else "")
        return group, fmt_step(config["dt"]), config["dtype"]
    extras = []
    if config["contact"] == "impulse":
        group = f"impulse ×{config['substeps']}" + (" toi" if config["time_of_impact"] else "")
        if config["iterations"] != 4:
            extras.append(f"it{config['iterations']}")
        if config["solver"] != "sequential":
            extras.append(config["solver"])
    else:
        group = "penalty"
        if config["penalty_friction"] != "spring":
            extras.append(config["penalty_friction"])
        if config["smooth"]:
            extras.append("smooth")
    if config["integrator"] != "semi_implicit":
        extras.append(config["integrator"])
    if config["dtype"] != "float32":
        extras.append(config["dtype"])
    return group, " ".join([fmt_step(config["dt"])] + extras), "all"


def config_text(scene: str, config: dict) -> str:
    """The configuration in words, for the tables.

    Args:
        scene: one of :data:`SCENE_NAMES`.
        config: a configuration dict.

    Returns:
        Every option it sets, comma-separated.
    """
    if scene == "tumble":
        return f"{config['integrator']}, {config['orientation'] or '—'}, {config['dtype']}"
    if config["contact"] == "impulse":
        text = (f"impulse ×{config['substeps']} substeps, {config['iterations']} it, "
                f"{config['solver']}" + (", toi" if config["time_of_impact"] else ""))
    else:
        text = (f"penalty, {config['penalty_friction']} friction"
                + (", smooth" if config["smooth"] else ""))
    if config["integrator"] != "semi_implicit":
        text += f", {config['integrator']}"
    return text + ("" if config["dtype"] == "float32" else f", {config['dtype']}")


def build(scene: str, config: dict):
    """``(model, params, state)`` of one scene under one configuration.

    Args:
        scene: one of :data:`SCENE_NAMES`.
        config: a configuration dict (see :func:`tumble_grid`, :func:`impulse`, :func:`penalty`).

    Returns:
        What :meth:`jaxrb.Scene.build` returns.
    """
    dtype = jnp.dtype(config["dtype"])
    if scene == "tumble":
        return tumble_scene().build(dt=config["dt"], integrator=config["integrator"],
                                    orientation=config["orientation"], dtype=dtype)
    factories = {"bounce": bounce_scene, "slide": slide_scene, "roll": roll_scene}
    if scene not in factories:
        raise ValueError(f"speed_error: unknown scene {scene!r}; valid: {', '.join(SCENE_NAMES)}")
    options = dict(dt=config["dt"], integrator=config["integrator"], contact=config["contact"],
                   substeps=config["substeps"], dtype=dtype)
    if config["contact"] == "impulse":
        options.update(iterations=config["iterations"], solver=config["solver"],
                       time_of_impact=config["time_of_impact"])
    else:
        options.update(penalty_friction=config["penalty_friction"])
        if config["smooth"]:
            options.update(penalty_width=1e-3)
    return factories[scene]().build(**grouped(options))
