"""What each contact model can be told: ``scene.build(dt, contact=rb.Impulse(...))`` or ``rb.Penalty(...)``.

Each option is documented once, here, with its default, and ``repr`` shows
them all (``print(rb.Impulse())``). A string ``contact="impulse"`` or
``"penalty"`` means the model with these defaults; ``"none"`` turns contact
off. Options every contact model shares (``contact_margin``,
``bounce_threshold``, the broadphase) stay keywords of :meth:`Scene.build`.

The model options used to be flat keywords of ``build`` (``iterations=8``,
``penalty_stiffness=2e4``); those still work, with a DeprecationWarning, for
one release. Scene files keep them flat (their format is unchanged):
:func:`grouped` turns such a flat dict into the grouped form.
"""

from __future__ import annotations

import dataclasses
import warnings
from typing import Optional, Union

import numpy as np

from jaxrb.model.types import PENALTY_FRICTIONS, SOLVERS, check_option, check_param_values, param_bounds


def _check_number(label, name, value, bounds, optional):
    if value is None and optional:
        return
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"{label}: {name!r} must be a number, got {value!r}")
    check_param_values(label, name, value, 3, bounds=bounds)


def _check_integer(label, name, value, low):
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
        raise ValueError(f"{label}: {name!r} must be an integer >= {low}, got {value!r}")


@dataclasses.dataclass(frozen=True)
class Impulse:
    """Impulse contact: the soft step's sequential impulses, Coulomb friction, restitution.

    Attributes:
        solver: ``"sequential"`` (Gauss–Seidel over the contact rows) or
            ``"jacobi"`` (all rows at once, with mass splitting; stacks sink
            deeper).
        iterations: passes per substep with the soft position correction, >= 1.
            1 or 2 also hold the common stacks; 4 leaves them the least drift.
        relax_iterations: passes per substep without it, >= 0 (they remove
            the velocity the correction added).
        hertz: stiffness (Hz) of the soft position correction; None: a quarter
            of the substep rate, 0.25·substeps/dt, the stiffest the soft step
            resolves (it is capped there anyway). A contact sinks by
            load/(m_eff ω²): a 10-box stack of 0.2 m cubes stands at 60 Hz,
            not at 30 Hz. ``Params.contact_hertz``.
        damping_ratio: damping ratio of that correction
            (``Params.contact_damping_ratio``).
        max_push_velocity: cap (m/s) on the speed that pushes overlaps apart
            (``Params.max_push_velocity``).
        smoothing: σ (m/s) of the smooth normal clamp
            (``Params.impulse_smoothing``); 0 is the exact clamp, larger
            values let gradients see contacts coming.
        time_of_impact: resolve fast impacts of spheres, circles, capsules and
            point masses against planes, and of sphere (circle) pairs, at their
            time inside the substep (:mod:`jaxrb.physics.contact.toi`).
    """

    solver: str = "sequential"
    iterations: int = 4
    relax_iterations: int = 1
    hertz: Optional[float] = None
    damping_ratio: float = 10.0
    max_push_velocity: float = 3.0
    smoothing: float = 0.0
    time_of_impact: bool = False

    def __post_init__(self):
        check_option("solver", self.solver, SOLVERS)
        _check_integer("rb.Impulse", "iterations", self.iterations, 1)
        _check_integer("rb.Impulse", "relax_iterations", self.relax_iterations, 0)
        for name in ("hertz", "damping_ratio", "max_push_velocity", "smoothing"):
            _check_number("rb.Impulse", name, getattr(self, name), param_bounds(IMPULSE_KEYWORDS[name]),
                          optional=name == "hertz")
        if not isinstance(self.time_of_impact, (bool, np.bool_)):
            raise ValueError(f"rb.Impulse: 'time_of_impact' must be True or False, got {self.time_of_impact!r}")


@dataclasses.dataclass(frozen=True)
class Penalty:
    """Penalty contact: spring-damper normal forces and Coulomb friction (:mod:`jaxrb.physics.contact.penalty`).

    Give the spring as ``stiffness`` (N/m) and ``damping`` (N·s/m) per contact
    point, or as ``frequency`` (Hz) and ``damping_ratio`` on the mean body
    mass m (k = m ω², c = 2ζ m ω). Without any, the frequency is 0.03/h
    (h = dt/substeps; stable for symplectic Euler with up to ~8 contacts on a
    body) and each contact's damper comes from its restitution (the clamped
    spring-damper's inverse).

    Attributes:
        stiffness: spring constant (N/m), or None (``Params.penalty_stiffness``).
        damping: damper (N·s/m), or None: from restitution
            (``Params.penalty_damping``).
        frequency: spring frequency (Hz) on the mean body mass, or None.
        damping_ratio: damping ratio on the mean body mass, or None.
        width: softplus width (m) of a smooth activation, or None for the hard
            one (``Params.penalty_width``); giving it turns the smooth one on.
        friction: ``"spring"`` (stick–slip: holds a load below the friction
            angle) or ``"regularized"`` (smooth Coulomb with
            ``friction_velocity``; creeps under a steady load).
        friction_velocity: regularisation speed v_reg (m/s) of the
            ``"regularized"`` law (``Params.friction_velocity``).
    """

    stiffness: Optional[float] = None
    damping: Optional[float] = None
    frequency: Optional[float] = None
    damping_ratio: Optional[float] = None
    width: Optional[float] = None
    friction: str = "spring"
    friction_velocity: float = 1e-4

    def __post_init__(self):
        check_option("penalty friction", self.friction, PENALTY_FRICTIONS)
        for name in ("stiffness", "damping", "width", "friction_velocity"):
            _check_number("rb.Penalty", name, getattr(self, name), param_bounds(PENALTY_KEYWORDS[name]),
                          optional=name != "friction_velocity")
        _check_number("rb.Penalty", "frequency", self.frequency, dict(low=0.0, high=None, low_open=True), True)
        _check_number("rb.Penalty", "damping_ratio", self.damping_ratio, dict(low=0.0, high=None, low_open=False),
                      True)


#: Each option's flat keyword of ``Scene.build`` (and the Params field, where one holds it).
IMPULSE_KEYWORDS = {"solver": "solver", "iterations": "iterations", "relax_iterations": "relax_iterations",
                    "hertz": "contact_hertz", "damping_ratio": "contact_damping_ratio",
                    "max_push_velocity": "max_push_velocity", "smoothing": "impulse_smoothing",
                    "time_of_impact": "time_of_impact"}
PENALTY_KEYWORDS = {"stiffness": "penalty_stiffness", "damping": "penalty_damping",
                    "frequency": "penalty_frequency", "damping_ratio": "penalty_damping_ratio",
                    "width": "penalty_width", "friction": "penalty_friction",
                    "friction_velocity": "friction_velocity"}
_GROUPS = {"impulse": (Impulse, IMPULSE_KEYWORDS), "penalty": (Penalty, PENALTY_KEYWORDS)}
#: flat keyword -> (contact model, option name)
FLAT_KEYWORDS = {flat: (model, name) for model, (_, table) in _GROUPS.items() for name, flat in table.items()}

Contact = Union[None, str, Impulse, Penalty]


def flat_options(contact: Contact, flat: dict) -> tuple:
    """``Scene.build``'s contact argument and its deprecated flat keywords as one flat set of options.

    Args:
        contact: None, ``"none"``, ``"impulse"``, ``"penalty"``, an
            :class:`Impulse` or a :class:`Penalty`.
        flat: flat model keywords given to ``build`` (deprecated), e.g.
            ``{"iterations": 8}``.

    Returns:
        ``(name, options)``: the contact model's name (None: ``build``
        chooses) and every model option by its flat keyword, the group's
        defaults included.

    Raises:
        ValueError: an unknown keyword, or one given both in a group and
            flat, or for the other model than the group's.
    """
    unknown = sorted(set(flat) - set(FLAT_KEYWORDS))
    if unknown:
        raise ValueError(f"scene.build: unknown option(s) {', '.join(map(repr, unknown))}; contact model options "
                         f"go in contact=rb.Impulse(...) or rb.Penalty(...)")
    if flat:
        by_model = {}
        for keyword in flat:
            model, name = FLAT_KEYWORDS[keyword]
            by_model.setdefault(model, []).append(f"{name}={flat[keyword]!r}")
        advice = "; ".join(f"contact=rb.{model.capitalize()}({', '.join(names)})" for model, names in by_model.items())
        warnings.warn(f"scene.build: the flat keywords {', '.join(map(repr, flat))} are deprecated and go away in "
                      f"the next release; pass {advice}", DeprecationWarning, stacklevel=3)
    # Both models' defaults: the Params fields of the model not chosen keep theirs.
    defaults = {flat_name: getattr(group(), option) for group, table in _GROUPS.values()
                for option, flat_name in table.items()}
    if isinstance(contact, (Impulse, Penalty)):
        name = "impulse" if isinstance(contact, Impulse) else "penalty"
        table = _GROUPS[name][1]
        if flat:
            raise ValueError(f"scene.build: {', '.join(map(repr, flat))} given beside contact={contact!r}; give a "
                             f"model's options in its group only")
        return name, {**defaults, **{flat_name: getattr(contact, option) for option, flat_name in table.items()}}
    if contact is not None and not isinstance(contact, str):
        raise ValueError(f"scene.build: 'contact' must be 'none', 'impulse', 'penalty', rb.Impulse(...) or "
                         f"rb.Penalty(...), got {contact!r}")
    return contact, {**defaults, **flat}


def grouped(options: dict) -> dict:
    """Flat build options (a scene file's, a benchmark grid's) in the grouped form ``Scene.build`` takes.

    Args:
        options: keyword -> value, e.g. ``{"dt": 0.004, "contact": "penalty",
            "penalty_stiffness": 8000.0}``.

    Returns:
        The same options with the model keywords moved into ``contact``, e.g.
        ``{"dt": 0.004, "contact": rb.Penalty(stiffness=8000.0)}``.

    Raises:
        ValueError: keywords of both models, or of a model other than the
            options' ``contact`` (unless at their defaults, where they do
            nothing and are dropped).
    """
    options = dict(options)
    flat = {keyword: options.pop(keyword) for keyword in list(options) if keyword in FLAT_KEYWORDS}
    contact = options.get("contact")
    if isinstance(contact, str):  # an option at its default does nothing for another model (or none)
        flat = {keyword: value for keyword, value in flat.items() if FLAT_KEYWORDS[keyword][0] == contact
                or value != getattr(_GROUPS[FLAT_KEYWORDS[keyword][0]][0](), FLAT_KEYWORDS[keyword][1])}
    if not flat:
        return options
    models = {FLAT_KEYWORDS[keyword][0] for keyword in flat}
    if len(models) > 1 or (isinstance(contact, str) and contact not in models):
        raise ValueError(f"build options: {', '.join(map(repr, flat))} are options of "
                         f"{' and '.join(sorted(models))} contact"
                         + (f", not of contact {contact!r}" if isinstance(contact, str) else ""))
    model = models.pop()
    group, table = _GROUPS[model]
    if isinstance(contact, (Impulse, Penalty)):
        raise ValueError(f"build options: {', '.join(map(repr, flat))} given beside contact={contact!r}")
    options["contact"] = group(**{FLAT_KEYWORDS[keyword][1]: value for keyword, value in flat.items()})
    return options


def flattened(options: dict) -> dict:
    """The inverse of :func:`grouped`: a contact group's options that differ from its defaults, by flat keyword.

    Args:
        options: build options, ``contact`` possibly an :class:`Impulse` or :class:`Penalty`.

    Returns:
        The options with ``contact`` a string and the group's non-default
        options as flat keywords (what a scene file stores).
    """
    options = dict(options)
    contact = options.get("contact")
    if isinstance(contact, (Impulse, Penalty)):
        name = "impulse" if isinstance(contact, Impulse) else "penalty"
        group, table = _GROUPS[name]
        default = group()
        options["contact"] = name
        for option, keyword in table.items():
            value = getattr(contact, option)
            if value != getattr(default, option):
                options[keyword] = value
    return options
