"""Smoothing knobs against gradient bias and spread, on the bounce and slide scenes.

Hard contact makes the outcome of a rollout a piecewise-smooth function of its
parameters: the step in which a contact switches on or a sliding body sticks
moves in jumps, and between the jumps the autodiff gradient sees none of the
switching (the impact-time term of a bounce, for one). The smoothing knobs
trade a bias in the forward result for a landscape without those jumps:

* penalty contact: the softplus activation of width w
  (``rb.Penalty(width=w)``, ``Params.penalty_width``) and the
  regularised Coulomb friction of slip velocity v_reg
  (``rb.Penalty(friction="regularized", friction_velocity=v_reg)``,
  ``Params.friction_velocity``);
* impulse contact: the soft complementarity σ (m/s) of the normal clamp
  (``rb.Impulse(smoothing=σ)``, ``Params.impulse_smoothing``).

For every knob value of a sweep this benchmark runs K worlds (``jax.vmap``)
whose one jittered parameter is spread evenly over a small window, and
differentiates a scalar outcome of the rollout with respect to two parameters
θ = (θ₁, θ₂) in each world. It reports, against the closed form of the
outcome:

* **value error**: mean over the K worlds of outcome − closed form: the
  bias the knob (and the time step) adds to the forward result;
* **bias**: mean over the K worlds of ∂outcome/∂θᵢ (autodiff) − closed-form
  derivative;
* **std**: standard deviation over the K worlds of that same gradient error.
  The closed-form derivative barely changes over the window, so this is the
  spread of the autodiff gradient itself: how jumpy the landscape is (a
  sawtooth value function has a gradient that swings over each tooth).

Scenes (the settings of ``tests/test_contact.py``):

* **bounce**: sphere r = 0.1 m, 1 kg, restitution 0.8 (sphere and plane), its
  lowest point dropped from h₀ = 0.9 m. θ = (h₀, e). Outcome: the apex gap of
  the first rebound, read as A = z − r + v_z²/(2g) at t = 0.75 s (in flight
  for every world and knob here, where z + v_z²/(2g) is constant, so the
  readout depends on no sampling of the apex). Closed form A = h₀e²,
  ∂A/∂h₀ = e², ∂A/∂e = 2eh₀. K worlds jitter h₀ by ±1 cm.
* **slide**: box half 0.1 m, 1 kg, launched at v₀ = 2 m/s along a plane,
  μ = 0.5 (box and plane: the mixed √(μ·μ) = μ). θ = (μ, v₀). Outcome: the
  distance d = x(T) − x(0) at T = 1 s (stopped at v₀/(μg) = 0.41 s). Closed
  form d = v₀²/(2μg), ∂d/∂μ = −v₀²/(2μ²g), ∂d/∂v₀ = v₀/(μg). K worlds jitter
  v₀ by ±1 %.

Each sweep compiles one function per Model (the knob is a Params field, so
all its values share the compile; only the sharp reference of a penalty
sweep, the hard activation or the stick–slip ``"spring"`` friction, is a
different Model). Gradients are forward mode: the vmapped batch holds every
world twice, once with tangent e₁ and once with e₂ (``jax.jvp``; the same
numbers as ``jax.grad`` to rounding, and it compiles several times faster
through the impulse solver's loops).

Why the activation-width sweep widens the contact margin. A penalty contact
exists only within ``contact_margin`` (+ dt·approach speed) of the plane, and
the softplus force there is k·w·softplus(−margin/w), not zero: with the
default 1 cm margin and w = 1 cm it is ~8 × the sphere's weight, switched on
in one step, and the rebound apex then jumps by 2.5 cm every 4 mm of h₀
(∂A/∂h₀ ≈ −15 between the jumps instead of 0.64). So the sweep sets
``contact_margin = max(margin, 20·w)`` (force at the margin below
k·w·e⁻²⁰); the ``*_default_margin`` sweep keeps the default margin to show
the effect.

What the full run measured (K = 32, float64; the numbers are in the report):

* penalty width, bounce: the hard activation and w ≤ 1 mm give a sawtooth
  apex (period v·h = 4.2 mm of h₀ at dt = 1 ms), ∂A/∂h₀ std 2.3-18;
  w = 3 mm (≈ v·h) gives std 2e-4 and bias 4e-5, at 11 mm value error; the
  value error then grows (10 cm at w = 1 cm). Rule: w of order the travel per
  step, margin ≫ w.
* regularised friction, slide: every setting has a usable gradient (std
  ≤ 1e-3); v_reg = 0.1 m/s cuts the spread 50-fold for a 3 mm (0.8 %) longer
  slide and a 1 % bias on ∂d/∂μ; 0.3 m/s costs 2.7 cm.
* impulse σ, bounce: without time of impact ∂A/∂h₀ is 1 instead of e² (the
  impact time is lost), whatever σ ≤ 0.1; σ = 1 m/s brings it to 0.5 with a
  spread of 0.2. σ does not smooth the stick of the slide (its spread stays
  5e-3 up to σ = 0.3).
"""

from __future__ import annotations

import dataclasses
import math
import os
from typing import Callable, Optional, Sequence

import jax
import jax.numpy as jnp
import numpy as np

import jaxrb as rb
from jaxrb.bench.report import fmt_sci, markdown_table
from jaxrb.bench.timing import Stopwatch, compile_jitted, time_compiled
from jaxrb.model.options import grouped

G = 9.81
RADIUS = 0.1
DROP_GAP = 0.9  # m, sphere's lowest point above the plane at release
RESTITUTION = 0.8
HALF = 0.1
FRICTION = 0.5
SLIDE_SPEED = 2.0
#: contact_margin >= this × penalty_width in the activation-width sweeps (see the module docs).
MARGIN_PER_WIDTH = 20.0


# --- scenes: outcome, parameters and closed forms ---------------------------------------------

@dataclasses.dataclass(frozen=True)
class Scenario:
    """A scene, a scalar outcome of its rollout, two parameters and their closed forms.

    Attributes:
        name: short name used in tables.
        description: one line for the report.
        param_names: names of θ₁, θ₂ as printed.
        outcome_name: symbol of the outcome as printed.
        nominal: (2,) nominal θ.
        jitter_index: which θ the K worlds spread over.
        jitter: half width of that spread (same unit as θ).
        horizon: seconds simulated before the outcome is read.
        make_scene: () -> rb.Scene at the nominal θ.
        apply: (θ (2,), params, state) -> (params, state) with θ written in.
        outcome: (final state, params) -> () scalar outcome.
        closed_form: θ (K, 2) numpy -> (K,) closed-form outcome.
        closed_grad: θ (K, 2) numpy -> (K, 2) closed-form derivatives.
    """

    name: str
    description: str
    param_names: tuple
    outcome_name: str
    nominal: tuple
    jitter_index: int
    jitter: float
    horizon: float
    make_scene: Callable
    apply: Callable
    outcome: Callable
    closed_form: Callable
    closed_grad: Callable

    def thetas(self, worlds: int) -> np.ndarray:
        """(K, 2) parameters of the K worlds: the jittered one evenly over ±jitter."""
        thetas = np.tile(np.asarray(self.nominal, dtype=np.float64), (worlds, 1))
        thetas[:, self.jitter_index] += np.linspace(-self.jitter, self.jitter, worlds) if worlds > 1 else 0.0
        return thetas


def _bounce_scene():
    scene = rb.Scene(dim=3)
    scene.add_plane(restitution=RESTITUTION)
    scene.add_body(rb.Sphere(RADIUS), mass=1.0, pos=(0.0, 0.0, RADIUS + DROP_GAP),
                   restitution=RESTITUTION)
    return scene


def _bounce_apply(theta, params, state):
    drop_gap, restitution = theta[0], theta[1]
    # Sphere and plane both get e, so the mixed max(e_A, e_B) is e.
    params = params.replace(restitution=jnp.full_like(params.restitution, restitution),
                            plane_restitution=jnp.full_like(params.plane_restitution, restitution))
    return params, state.replace(pos=state.pos.at[0, 2].set(RADIUS + drop_gap))


def _bounce_outcome(state, params):
    # In flight z + v²/(2g) is the apex whatever the phase of the readout.
    gravity = -params.gravity[2]
    return state.pos[0, 2] - RADIUS + state.vel[0, 2] ** 2 / (2.0 * gravity)


def _slide_scene():
    scene = rb.Scene(dim=3)
    scene.add_plane(friction=FRICTION)
    scene.add_body(rb.Box((HALF,) * 3), mass=1.0, pos=(0.0, 0.0, HALF),
                   vel=(SLIDE_SPEED, 0.0, 0.0), friction=FRICTION)
    return scene


def _slide_apply(theta, params, state):
    friction, speed = theta[0], theta[1]
    # Box and plane both get μ, so the mixed √(μ_A μ_B) is μ.
    params = params.replace(friction=jnp.full_like(params.friction, friction),
                            plane_friction=jnp.full_like(params.plane_friction, friction))
    return params, state.replace(vel=state.vel.at[0, 0].set(speed))


def _slide_outcome(state, params):
    return state.pos[0, 0]


SCENARIOS = {
    "bounce": Scenario(
        name="bounce", description=f"sphere r={RADIUS} m dropped from a {DROP_GAP} m gap, e={RESTITUTION}",
        param_names=("h₀", "e"), outcome_name="A", nominal=(DROP_GAP, RESTITUTION), jitter_index=0,
        jitter=0.01, horizon=0.75, make_scene=_bounce_scene, apply=_bounce_apply,
        outcome=_bounce_outcome,
        closed_form=lambda th: th[:, 0] * th[:, 1] ** 2,
        closed_grad=lambda th: np.stack([th[:, 1] ** 2, 2.0 * th[:, 1] * th[:, 0]], axis=1)),
    "slide": Scenario(
        name="slide", description=f"box half {HALF} m, 1 kg, v₀={SLIDE_SPEED} m/s, μ={FRICTION}",
        param_names=("μ", "v₀"), outcome_name="d", nominal=(FRICTION, SLIDE_SPEED), jitter_index=1,
        jitter=0.01 * SLIDE_SPEED, horizon=1.0, make_scene=_slide_scene, apply=_slide_apply,
        outcome=_slide_outcome,
        closed_form=lambda th: th[:, 1] ** 2 / (2.0 * th[:, 0] * G),
        closed_grad=lambda th: np.stack([-th[:, 1] ** 2 / (2.0 * th[:, 0] ** 2 * G),
                                         th[:, 1] / (th[:, 0] * G)], axis=1)),
}


# --- sweeps: a knob on one contact model of one scene ------------------------------------------

@dataclasses.dataclass(frozen=True)
class Sweep:
    """One knob swept on one scene and contact model.

    Attributes:
        name: key in :data:`SWEEPS`.
        scenario: key in :data:`SCENARIOS`.
        contact: ``"penalty"`` or ``"impulse"``.
        field: the Params field the knob sets.
        knob_label: the knob as printed (with its unit).
        knobs: knob values; 0 is the sharp reference (see ``sharp_build``).
        build: ``scene.build`` settings of the smoothed model.
        sharp_build: settings of the Model that knob 0 runs on when it is not
            the same Model (``None``: knob 0 is a plain Params value).
        sharp_label: how knob 0 is printed.
        margin_per_knob: if set, ``contact_margin = max(margin, this·knob)``.
    """

    name: str
    scenario: str
    contact: str
    field: str
    knob_label: str
    knobs: tuple
    build: dict
    sharp_build: Optional[dict] = None
    sharp_label: str = "0"
    margin_per_knob: Optional[float] = None


_BOUNCE_IMPULSE = dict(dt=1 / 240, substeps=4)  # the apex test's setting (impact timing O(h))
_SLIDE_IMPULSE = dict(dt=1 / 60, substeps=4)
_PENALTY = dict(dt=1e-3, substeps=1)
_WIDTHS = (0.0, 1e-4, 1e-3, 3e-3, 1e-2, 3e-2)
_SIGMAS = (0.0, 0.01, 0.03, 0.1, 0.3, 1.0)

SWEEPS = {
    "bounce_penalty_width": Sweep(
        "bounce_penalty_width", "bounce", "penalty", "penalty_width", "width w (m)", _WIDTHS,
        dict(_PENALTY, penalty_width=1e-3), sharp_build=dict(_PENALTY), sharp_label="hard",
        margin_per_knob=MARGIN_PER_WIDTH),
    "bounce_penalty_width_default_margin": Sweep(
        "bounce_penalty_width_default_margin", "bounce", "penalty", "penalty_width",
        "width w (m), margin 1 cm", _WIDTHS[1:], dict(_PENALTY, penalty_width=1e-3)),
    "bounce_impulse": Sweep(
        "bounce_impulse", "bounce", "impulse", "impulse_smoothing", "σ (m/s)", _SIGMAS,
        dict(_BOUNCE_IMPULSE)),
    "bounce_impulse_toi": Sweep(
        "bounce_impulse_toi", "bounce", "impulse", "impulse_smoothing", "σ (m/s), time of impact",
        _SIGMAS, dict(_BOUNCE_IMPULSE, time_of_impact=True)),
    "slide_penalty_friction": Sweep(
        "slide_penalty_friction", "slide", "penalty", "friction_velocity", "v_reg (m/s)",
        (0.0, 1e-4, 1e-3, 1e-2, 0.1, 0.3), dict(_PENALTY, penalty_friction="regularized"),
        sharp_build=dict(_PENALTY), sharp_label="spring"),
    "slide_impulse": Sweep(
        "slide_impulse", "slide", "impulse", "impulse_smoothing", "σ (m/s)", _SIGMAS,
        dict(_SLIDE_IMPULSE)),
}

#: Settings for ``python -m jaxrb.bench`` (merge into its SETTINGS per mode). Quick
#: runs one penalty sweep without its sharp Model: one compile of about 8 s (the
#: friction sweep's took 10 s more, the impulse sweep's gradient alone 24 s).
SETTINGS = {
    "quick": dict(smoothing_worlds=8, smoothing_sweeps=("bounce_penalty_width",),
                  smoothing_knobs={"bounce_penalty_width": (1e-4, 1e-3, 3e-3, 1e-2)}),
    "full": dict(smoothing_worlds=32, smoothing_sweeps=tuple(SWEEPS), smoothing_knobs=None),
}


@dataclasses.dataclass
class SmoothingRow:
    """Measurements of one knob value of one sweep (K worlds).

    Attributes:
        sweep, scene, contact: what ran.
        knob_label: the knob as printed in the header; knob: its value;
            knob_text: the value as printed (``"hard"`` for a sharp Model).
        worlds: K.
        value_error: mean over worlds of outcome − closed form.
        value_spread: std over worlds of outcome − closed form.
        grad_closed: (2,) mean closed-form derivative.
        grad_mean: (2,) mean autodiff derivative.
        grad_bias: (2,) mean of autodiff − closed form.
        grad_std: (2,) std of autodiff − closed form.
        compile_s: compile time of the function this row ran on (shared by
            the rows of one Model).
        run_s: wall seconds of the one call for this knob value.
    """

    sweep: str
    scene: str
    contact: str
    knob_label: str
    knob: float
    knob_text: str
    worlds: int
    value_error: float
    value_spread: float
    grad_closed: tuple
    grad_mean: tuple
    grad_bias: tuple
    grad_std: tuple
    compile_s: float
    run_s: float

    def figures(self) -> list:
        """Every measured number of the row (all must be finite)."""
        return [self.value_error, self.value_spread, *self.grad_closed, *self.grad_mean,
                *self.grad_bias, *self.grad_std, self.compile_s, self.run_s]


def outcome_and_derivative_fn(scenario: Scenario, model, state, num_steps: int) -> Callable:
    """``f(thetas, tangents, params) -> (values, directional)`` over a batch of worlds.

    Args:
        scenario: the scene's outcome and parameter mapping.
        model, state: the built scene (state at the nominal θ).
        num_steps: steps of the rollout before the outcome is read.

    Returns:
        A function of thetas (R, 2), tangents (R, 2) and one Params shared by
        all rows (the knob is set in it), returning the outcome (R,) and its
        derivative along each row's tangent (R,), by forward mode through the
        whole rollout.
    """
    step = rb.make_step(model)

    def outcome(theta, params):
        params_theta, state_theta = scenario.apply(theta, params, state)

        def advance(current, _):
            return step(current, params_theta), None

        final, _ = jax.lax.scan(advance, state_theta, None, length=num_steps)
        return scenario.outcome(final, params_theta)

    def one_world(theta, tangent, params):
        return jax.jvp(lambda t: outcome(t, params), (theta,), (tangent,))

    return jax.vmap(one_world, in_axes=(0, 0, None))


def _check_finite(row: SmoothingRow):
    if not all(math.isfinite(float(v)) for v in row.figures()):
        raise FloatingPointError(f"smoothing bench {row.sweep} knob {row.knob_text}: non-finite "
                                 f"figure in {row.figures()}")


def run_sweep(sweep: Sweep, worlds: int, knobs: Optional[Sequence[float]] = None, log=None,
              compiled_cache: Optional[dict] = None) -> list:
    """Measure one sweep; return one :class:`SmoothingRow` per knob value.

    Args:
        sweep: what to run.
        worlds: K, the number of jittered worlds.
        knobs: knob values (default ``sweep.knobs``); 0 is the sharp reference.
        log: optional progress callback taking a string.
        compiled_cache: optional dict shared between sweeps so sweeps on the
            same scene and Model reuse one compiled function.
    """
    log = log or (lambda text: None)
    cache = {} if compiled_cache is None else compiled_cache
    scenario = SCENARIOS[sweep.scenario]
    knobs = sweep.knobs if knobs is None else tuple(knobs)
    thetas_np = scenario.thetas(worlds)
    # Every world twice: once along θ₁, once along θ₂.
    thetas = np.repeat(thetas_np, 2, axis=0)
    tangents = np.tile(np.eye(2), (worlds, 1))
    closed = scenario.closed_form(thetas_np)
    closed_grad = scenario.closed_grad(thetas_np)
    rows = []
    for knob in knobs:
        sharp = knob == 0.0 and sweep.sharp_build is not None
        build = sweep.sharp_build if sharp else sweep.build
        key = (sweep.scenario, sweep.contact, tuple(sorted(build.items())), worlds)
        if key not in cache:
            model, params, state = scenario.make_scene().build(**grouped(dict(build, contact=sweep.contact)))
            num_steps = int(round(scenario.horizon / float(params.dt)))
            fn = outcome_and_derivative_fn(scenario, model, state, num_steps)
            args = (jnp.asarray(thetas, params.dt.dtype), jnp.asarray(tangents, params.dt.dtype), params)
            compiled, compile_s = compile_jitted(fn, *args)
            log(f"smoothing {sweep.scenario:>6} {sweep.contact:>7} {'sharp' if sharp else 'smooth'} model: "
                f"compile {compile_s:.1f} s")
            cache[key] = (compiled, compile_s, params, args[:2])
        compiled, compile_s, params, args = cache[key]
        if not sharp:
            params = params.replace(**{sweep.field: jnp.asarray(knob, params.dt.dtype)})
            if sweep.margin_per_knob is not None:
                params = params.replace(contact_margin=jnp.maximum(
                    params.contact_margin, jnp.asarray(sweep.margin_per_knob * knob, params.dt.dtype)))
        run_s, _, (values, directional) = time_compiled(compiled, *args, params, repeats=1, warmup=0)
        values = np.asarray(values)[::2]
        grads = np.asarray(directional).reshape(worlds, 2)
        error = grads - closed_grad
        row = SmoothingRow(
            sweep=sweep.name, scene=sweep.scenario, contact=sweep.contact, knob_label=sweep.knob_label,
            knob=float(knob), knob_text=sweep.sharp_label if sharp else f"{knob:g}", worlds=worlds,
            value_error=float(np.mean(values - closed)), value_spread=float(np.std(values - closed)),
            grad_closed=tuple(map(float, closed_grad.mean(axis=0))),
            grad_mean=tuple(map(float, grads.mean(axis=0))),
            grad_bias=tuple(map(float, error.mean(axis=0))),
            grad_std=tuple(map(float, error.std(axis=0))),
            compile_s=compile_s, run_s=run_s)
        _check_finite(row)
        log(f"smoothing {sweep.name:>36} {row.knob_text:>7}: value err {row.value_error:+.2e}, "
            f"bias {row.grad_bias[0]:+.2e} {row.grad_bias[1]:+.2e}, "
            f"std {row.grad_std[0]:.2e} {row.grad_std[1]:.2e}")
        rows.append(row)
    return rows


def run(settings: dict, log=None) -> list:
    """Run the sweeps named in ``settings``; return every :class:`SmoothingRow`.

    Args:
        settings: ``smoothing_worlds`` (K, default 32), ``smoothing_sweeps``
            (names in :data:`SWEEPS`, default all), ``smoothing_knobs``
            (optional ``{sweep name: knob values}`` overriding the defaults).
            Other keys are ignored, so the command line's settings dict can be
            passed whole.
        log: optional progress callback taking a string.
    """
    worlds = int(settings.get("smoothing_worlds", 32))
    if worlds < 2:
        raise ValueError(f"smoothing: 'smoothing_worlds' must be >= 2 (a spread needs worlds), got {worlds}")
    names = settings.get("smoothing_sweeps") or tuple(SWEEPS)
    unknown = [name for name in names if name not in SWEEPS]
    if unknown:
        raise ValueError(f"smoothing: unknown 'smoothing_sweeps' {unknown}; valid: {', '.join(SWEEPS)}")
    overrides = settings.get("smoothing_knobs") or {}
    cache: dict = {}
    rows = []
    for name in names:
        rows.extend(run_sweep(SWEEPS[name], worlds, overrides.get(name), log=log, compiled_cache=cache))
    return rows


# --- output -------------------------------------------------------------------------------------

def format_table(rows: Sequence[SmoothingRow]) -> str:
    """Markdown: one table per scene, one line per sweep and knob value."""
    parts = []
    for name in dict.fromkeys(row.scene for row in rows):
        scenario = SCENARIOS[name]
        scene_rows = [row for row in rows if row.scene == name]
        first, second = scenario.param_names
        out = scenario.outcome_name
        closed = np.mean([row.grad_closed for row in scene_rows], axis=0)
        parts.append(
            f"**{name}** ({scenario.description}; K = {scene_rows[0].worlds} worlds, "
            f"{scenario.param_names[scenario.jitter_index]} jittered by ±{scenario.jitter:g}). "
            f"Closed-form ∂{out}/∂{first} ≈ {closed[0]:.4g}, ∂{out}/∂{second} ≈ {closed[1]:.4g}.")
        parts.append("")
        parts.append(markdown_table(
            ["contact", "knob", "setting", f"{out} err (m)", f"{out} spread (m)",
             f"∂{out}/∂{first} bias", f"∂{out}/∂{first} std",
             f"∂{out}/∂{second} bias", f"∂{out}/∂{second} std", "compile (s)", "run (s)"],
            [[row.contact, row.knob_label, row.knob_text, fmt_sci(row.value_error), fmt_sci(row.value_spread),
              fmt_sci(row.grad_bias[0]), fmt_sci(row.grad_std[0]),
              fmt_sci(row.grad_bias[1]), fmt_sci(row.grad_std[1]),
              f"{row.compile_s:.1f}", f"{row.run_s:.2f}"] for row in scene_rows],
            align=["l", "l", "r", "r", "r", "r", "r", "r", "r", "r", "r"]))
        parts.append("")
    return "\n".join(parts).strip()


def plot(rows: Sequence[SmoothingRow], path: str) -> str:
    """PNG of |bias| and std of both derivatives, and |value error|, against the knob.

    One panel per sweep; the knob axis is categorical (the sharp reference 0
    sits on it). Returns ``path``.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sweeps = list(dict.fromkeys(row.sweep for row in rows))
    columns = min(3, len(sweeps))
    lines = math.ceil(len(sweeps) / columns)
    figure, axes = plt.subplots(lines, columns, figsize=(5.0 * columns, 3.8 * lines), squeeze=False)
    floor = 1e-12  # exact zeros (a gradient that sees nothing) drawn at the floor of the log axis
    for axis, name in zip(axes.flat, sweeps):
        sweep_rows = [row for row in rows if row.sweep == name]
        names = SCENARIOS[sweep_rows[0].scene].param_names
        where = np.arange(len(sweep_rows))
        for index, (marker, colour) in enumerate((("o", "C0"), ("s", "C1"))):
            axis.plot(where, [max(abs(r.grad_bias[index]), floor) for r in sweep_rows], marker + "-",
                      color=colour, label=f"|bias| ∂/∂{names[index]}")
            axis.plot(where, [max(r.grad_std[index], floor) for r in sweep_rows], marker + "--",
                      color=colour, label=f"std ∂/∂{names[index]}")
        axis.plot(where, [max(abs(r.value_error), floor) for r in sweep_rows], "k^:", label="|value err| (m)")
        axis.set_xticks(where, [r.knob_text for r in sweep_rows])
        axis.set_yscale("log")
        axis.set_xlabel(sweep_rows[0].knob_label)
        axis.set_title(f"{sweep_rows[0].scene} / {sweep_rows[0].contact}: {name}", fontsize=9)
        axis.grid(True, which="both", alpha=0.3)
        axis.legend(fontsize=7)
    for axis in list(axes.flat)[len(sweeps):]:
        axis.set_visible(False)
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)
    return path


def smoothing_section(settings: dict, log=None, out_dir: Optional[str] = None):
    """Run :func:`run` and return ``(markdown, rows)``; with ``out_dir`` also write smoothing.png."""
    with Stopwatch() as watch:
        rows = run(settings, log=log)
    text = [
        "Each smoothing knob trades a bias in the forward result for a gradient that sees contacts "
        "coming. Per knob value, K worlds (vmap) spread one parameter evenly over a small window; the "
        "outcome and its derivatives (forward-mode autodiff through the whole rollout) are compared "
        "with the closed form. *err* = mean(outcome − closed form), *spread* = its std; "
        "*bias* = mean(autodiff − closed-form derivative), *std* = its std over the K worlds (how "
        "jumpy the landscape is). The bounce outcome A is the rebound apex gap z − r + v_z²/(2g) read "
        "at t = 0.75 s in flight (closed form h₀e²); the slide outcome d is the distance at t = 1 s "
        "(closed form v₀²/(2μg)). Penalty at dt = 1 ms; impulse bounce at dt = 1/240 s, slide at "
        "1/60 s, 4 substeps. Activation-width sweeps set contact_margin = max(1 cm, "
        f"{MARGIN_PER_WIDTH:g}·w) unless marked *margin 1 cm*. The sharp references: *hard* "
        "activation, *spring* (stick–slip) friction, σ = 0. compile: once per Model, shared by its "
        "knob values; run: one call for K worlds × 2 directions.",
        "",
        format_table(rows),
    ]
    if out_dir is not None:
        os.makedirs(out_dir, exist_ok=True)
        path = plot(rows, os.path.join(out_dir, "smoothing.png"))
        text += ["", f"![smoothing knobs: |bias| and std against the knob]({os.path.basename(path)})"]
    text += ["", f"Smoothing sweeps wall time: {watch.seconds:.1f} s."]
    return "\n".join(text), rows
