"""System identification: fit ``Params`` fields to observed trajectories with optax.

The pieces, each usable alone:

* :class:`Observation`: what was measured, at which step indices (sparse and
  noisy is fine), with an optional per-sample mask.
* :func:`trajectory_loss`: weighted position, orientation and velocity errors
  between a rollout and an :class:`Observation`.
* :func:`to_unconstrained` / :func:`from_unconstrained`: the parameter
  transforms that keep fitted values physical whatever the optimiser does.
* :func:`fit`: the optax loop. Its update step (rollout, loss, gradient and
  optimiser update) is jitted once per call and reused for every iteration.

Parameter transforms (the default for each field is in :data:`DEFAULT_TRANSFORMS`):

``"log"``: value = exp(u). Used for everything that must stay positive: mass,
    2D inertia, friction, damping, stiffness. The optimiser then moves in
    relative terms (a step of 0.05 in u is a 5 % change), so one learning rate
    suits masses of grams and of tonnes. Friction ≥ 0 is kept > 0 this way;
    μ = 0 itself is out of reach (use ``"softplus"`` to approach it linearly).
``"softplus"``: value = log(1 + exp(u)), positive and linear for large values.
``"sigmoid"``: value = 1 / (1 + exp(−u)), in (0, 1): restitution.
``"second_moment"``: 3D inertia, the default. Per body the six unconstrained
    numbers fill a lower-triangular L (log-diagonal), C = L Lᵀ is a positive
    definite "second moment" matrix Σ m x xᵀ and I = tr(C)·Id − C, exactly the
    formula that builds inertia from point masses. Every such I is symmetric
    positive definite *and* its principal moments obey the triangle inequality
    (I₁ + I₂ − I₃ = 2 c₃ > 0, with c₃ an eigenvalue of C), so no value of u gives
    an inertia that no real body has. It fits the full tensor (principal moments
    and axes) with no singular parametrisation of the axes (unlike Euler angles).
``"principal"``: 3D inertia known to be diagonal in the body frame (the
    primitives' frames): C = diag(exp(u)), three numbers per body, the same
    guarantees. Fewer unknowns when the axes are known.
``"identity"``: value = u (gravity, forces, centre-of-mass offsets).
``"clip"``: value = clip(u, 0, 1), the closed interval: a restitution that
    starts at 0 or may end there (the sigmoid only approaches 0). Flat outside
    [0, 1], and at a bound JAX's gradient is half the slope inside, so a
    gradient method can leave 0 but is not pushed back into the interval.

Early stopping (off by default): with ``tol`` set, :func:`fit` stops when the
best loss of the last ``patience`` iterations is less than a fraction ``tol``
below the best loss before them, i.e. the fit has stopped improving in
relative terms. A window rather than consecutive steps, because Adam's loss
oscillates from step to step near a minimum. It also stops, with a warning, at
a non-finite loss. In every case the returned parameters are those with the
lowest loss seen.
"""

from __future__ import annotations

import dataclasses
import math
import time
import warnings
from typing import Callable, Mapping, NamedTuple, Optional, Sequence, Union

import jax
import jax.numpy as jnp
import numpy as np
import optax

from jaxrb import adjoint as hand_written
from jaxrb._struct import pytree_dataclass
from jaxrb.compile import jit
from jaxrb.math import safe_norm
from jaxrb.step import rollout
from jaxrb.types import DERIVED_PARAMS, Params, State, Wrench

Array = jax.Array
PARAM_FIELDS = tuple(field.name for field in dataclasses.fields(Params) if field.name not in DERIVED_PARAMS)


# --- observations and losses -------------------------------------------------------

@pytree_dataclass
class Observation:
    """An observed trajectory of one world (or, with a leading batch axis B, of several).

    Attributes:
        steps: (T,) int step indices k >= 1: sample t is the state after
            ``steps[t]`` calls of ``step`` from the initial state. Need not be
            evenly spaced.
        pos: (T, n, dim) centre-of-mass positions, or None.
        quat: (T, n, 4) unit quaternions (w, x, y, z), 3D only, or None.
        angle: (T, n) angles, 2D only, or None.
        vel: (T, n, dim) linear velocities, or None.
        angvel: (T, n, 3) world angular velocities in 3D, (T, n) in 2D, or None.
        mask: (T, n) weights (1 observed, 0 missing), or None for all observed.
        time: (T,) the simulated time (s) of each sample as the rollout
            recorded it (``State.time``), or None (measured data). :func:`fit`
            checks it against the initial time plus ``steps``·dt, so samples
            labelled with the wrong steps (``observe``'s ``every`` taken as
            "keep every k-th sample") are an error, not a silently wrong fit.
    """

    steps: Array
    pos: Optional[Array] = None
    quat: Optional[Array] = None
    angle: Optional[Array] = None
    vel: Optional[Array] = None
    angvel: Optional[Array] = None
    mask: Optional[Array] = None
    time: Optional[Array] = None


def observe(states: State, steps: Optional[Sequence[int]] = None, *, every: int = 1,
            velocities: bool = False) -> Observation:
    """An :class:`Observation` taken from a stacked rollout (e.g. to make synthetic data).

    Args:
        states: State with a leading time axis, from ``rollout(..., every=every)``
            (its sample i is the state after ``every·(i + 1)`` steps).
        steps: (T,) step indices to keep, multiples of ``every``; default all.
            To keep every 10th state of an every-step rollout, pass
            ``steps=range(10, T + 1, 10)``.
        every: the ``every`` the rollout was run with (not a thinning:
            :func:`fit` raises if the states' times disagree with it).
        velocities: also record ``vel`` and ``angvel``.

    Returns:
        The Observation (positions and orientations, velocities if asked).
    """
    num_saved = states.pos.shape[0]
    if steps is None:
        steps = every * np.arange(1, num_saved + 1)
    steps = np.asarray(steps)
    if steps.ndim != 1 or np.any(steps < every) or np.any(steps % every) or np.any(steps > every * num_saved):
        raise ValueError(f"observe: 'steps' must be multiples of every={every} in "
                         f"[{every}, {every * num_saved}], got {steps.tolist()}")
    index = steps // every - 1
    take = lambda a: None if a is None else jnp.asarray(a)[index]  # noqa: E731
    return Observation(steps=jnp.asarray(steps, dtype=jnp.int32), pos=take(states.pos),
                       quat=take(states.quat), angle=take(states.angle),
                       vel=take(states.vel) if velocities else None,
                       angvel=take(states.angvel) if velocities else None, time=take(states.time))


@dataclasses.dataclass(frozen=True)
class LossWeights:
    """Weights of the terms of :func:`trajectory_loss` (a term without data counts 0).

    Units: position and velocity terms are squared lengths (m², (m/s)²),
    orientation and angular velocity squared angles (rad², (rad/s)²). For a
    body of size ℓ, an orientation weight near ℓ² makes a rotation count like
    the distance its surface moves.

    Attributes:
        position: weight of the mean squared position error.
        orientation: weight of the mean squared orientation angle.
        velocity: weight of the mean squared velocity error.
        angvel: weight of the mean squared angular velocity error.
    """

    position: float = 1.0
    orientation: float = 1.0
    velocity: float = 1.0
    angvel: float = 1.0


def quaternion_angle(quat, target):
    """Rotation angle (rad) between two orientations, in [0, π].

    θ = 2·atan2(|v|, |w|) with (w, v) = q̂* ⊗ q, so q and −q count as the same
    orientation. ``safe_norm`` keeps the gradient finite (zero) at θ = 0, where
    arccos(|q·q̂|) would divide by zero.

    Args:
        quat: (..., 4) unit quaternions (w, x, y, z).
        target: (..., 4) unit quaternions q̂ to compare with.

    Returns:
        (...) angles in [0, π].
    """
    w = jnp.sum(quat * target, axis=-1)  # scalar part of conj(target) ⊗ quat
    tw, tv = target[..., :1], target[..., 1:]
    qw, qv = quat[..., :1], quat[..., 1:]
    cross = jnp.stack([tv[..., 1] * qv[..., 2] - tv[..., 2] * qv[..., 1],
                       tv[..., 2] * qv[..., 0] - tv[..., 0] * qv[..., 2],
                       tv[..., 0] * qv[..., 1] - tv[..., 1] * qv[..., 0]], axis=-1)
    vector = tw * qv - qw * tv - cross
    return 2.0 * jnp.arctan2(safe_norm(vector), jnp.abs(w))


def wrapped_angle(angle, target):
    """angle − target wrapped into (−π, π]. Smooth except at ±π.

    Args:
        angle: (...) angles (rad).
        target: (...) angles (rad) to compare with.

    Returns:
        (...) the wrapped differences.
    """
    difference = angle - target
    return jnp.arctan2(jnp.sin(difference), jnp.cos(difference))


def _masked_mean(error, mask):
    """Mean of ``error`` (T, n) over the samples with mask weight."""
    if mask is None:
        return jnp.mean(error)
    mask = jnp.asarray(mask, dtype=error.dtype)
    return jnp.sum(error * mask) / jnp.maximum(jnp.sum(mask), 1.0)


def trajectory_loss(predicted: State, observed: Observation,
                    weights: Union[LossWeights, Mapping[str, float], None] = None):
    """Weighted mean squared error of a rollout at the observed samples.

    ``loss = w_p·mean|Δpos|² + w_o·mean θ² + w_v·mean|Δvel|² + w_ω·mean|Δangvel|²``
    with means over the observed (sample, body) pairs and θ the 3D geodesic
    angle (:func:`quaternion_angle`) or the wrapped 2D angle difference.
    A term is left out when ``observed`` lacks its data. Zero at the truth,
    with a finite gradient there.

    Args:
        predicted: State sampled at the observation times: arrays (T, n, ...),
            e.g. ``rollout(...)`` indexed at ``observed.steps``.
        observed: the Observation (one world, no batch axis).
        weights: :class:`LossWeights` or a dict of its fields.

    Returns:
        () the scalar loss.
    """
    weights = _loss_weights(weights)
    mask = observed.mask
    total = 0.0
    if observed.pos is not None and weights.position:
        total = total + weights.position * _masked_mean(
            jnp.sum((predicted.pos - observed.pos) ** 2, axis=-1), mask)
    if weights.orientation:
        if observed.quat is not None:
            total = total + weights.orientation * _masked_mean(
                quaternion_angle(predicted.quat, observed.quat) ** 2, mask)
        elif observed.angle is not None:
            total = total + weights.orientation * _masked_mean(
                wrapped_angle(predicted.angle, observed.angle) ** 2, mask)
    if observed.vel is not None and weights.velocity:
        total = total + weights.velocity * _masked_mean(
            jnp.sum((predicted.vel - observed.vel) ** 2, axis=-1), mask)
    if observed.angvel is not None and weights.angvel:
        error = (predicted.angvel - observed.angvel) ** 2
        total = total + weights.angvel * _masked_mean(
            jnp.sum(error, axis=-1) if error.ndim == 3 else error, mask)
    return jnp.asarray(total)


def _loss_weights(weights) -> LossWeights:
    if weights is None:
        return LossWeights()
    if isinstance(weights, LossWeights):
        return weights
    valid = {f.name for f in dataclasses.fields(LossWeights)}
    for name, value in dict(weights).items():
        if name not in valid:
            raise ValueError(f"sysid: unknown loss weight {name!r}; valid: {', '.join(sorted(valid))}")
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
            raise ValueError(f"sysid: loss weight {name!r} must be a finite number >= 0, got {value!r}")
    return LossWeights(**dict(weights))


# --- parameter transforms ----------------------------------------------------------

class Transform(NamedTuple):
    """A bijection between a Params field and unconstrained numbers.

    Attributes:
        forward: unconstrained array -> field value (any u gives a valid value).
        inverse: field value -> unconstrained array (host side, at the start of a fit).
        name: used in messages.
    """

    forward: Callable
    inverse: Callable
    name: str


def _check_open(name, low=None, high=None, closed=False):
    """Wrap an inverse so values outside its domain raise a ValueError naming the field.

    The domain is the open interval (low, high), or with ``closed`` [low, high].
    """
    def check(field, value):
        array = np.asarray(value)
        below = low is not None and np.any(array < low if closed else array <= low)
        above = high is not None and np.any(array > high if closed else array >= high)
        if below or above:
            left, right = ("[", "]") if closed else ("(", ")")
            bounds = f"{left}{low if low is not None else '-inf'}, {high if high is not None else 'inf'}{right}"
            raise ValueError(f"sysid: field {field!r} has values {array.tolist()} outside the "
                             f"{'closed' if closed else 'open'} interval {bounds} of its {name!r} transform; "
                             f"start the fit from a value inside it")
    return check


def _second_moment_forward(u):
    """(n, 6) -> (n, 3, 3): L lower-triangular (log diagonal), C = L Lᵀ, I = tr(C)·Id − C."""
    zero = jnp.zeros_like(u[..., 0])
    rows = [[jnp.exp(u[..., 0]), zero, zero],
            [u[..., 3], jnp.exp(u[..., 1]), zero],
            [u[..., 4], u[..., 5], jnp.exp(u[..., 2])]]
    lower = jnp.stack([jnp.stack(row, axis=-1) for row in rows], axis=-2)
    # In float32 on GPUs too, where XLA's default may be TF32 (jaxrb.compile).
    second_moment = jnp.matmul(lower, jnp.swapaxes(lower, -1, -2), precision=jax.lax.Precision.HIGHEST)
    trace = jnp.trace(second_moment, axis1=-2, axis2=-1)[..., None, None]
    return trace * jnp.eye(3, dtype=u.dtype) - second_moment


def _second_moment_from_inertia(inertia):
    """C = tr(I)/2·Id − I (the inverse of I = tr(C)·Id − C). inertia: (..., 3, 3)."""
    inertia = 0.5 * (inertia + np.swapaxes(inertia, -1, -2))
    trace = np.trace(inertia, axis1=-2, axis2=-1)[..., None, None]
    return 0.5 * trace * np.eye(3) - inertia


# C of a flat body (I₃ = I₁ + I₂) is singular; its smallest eigenvalue is lifted
# to this fraction of the largest so the Cholesky factor (and log) exist.
_FLAT_FLOOR = 1e-9


def _second_moment_inverse(inertia):
    second_moment = _second_moment_from_inertia(np.asarray(inertia, dtype=np.float64))
    values, vectors = np.linalg.eigh(second_moment)
    values = np.maximum(values, _FLAT_FLOOR * values.max(axis=-1, keepdims=True))
    second_moment = (vectors * values[..., None, :]) @ np.swapaxes(vectors, -1, -2)
    lower = np.linalg.cholesky(second_moment)
    diagonal = np.log(np.diagonal(lower, axis1=-2, axis2=-1))
    return np.concatenate([diagonal, lower[..., [1, 2, 2], [0, 0, 1]]], axis=-1)


def _check_inertia(field, value):
    array = np.asarray(value, dtype=np.float64)
    if array.shape[-2:] != (3, 3):
        raise ValueError(f"sysid: field {field!r} must be (n, 3, 3) for a 3D inertia transform, "
                         f"got shape {array.shape}")
    moments = np.linalg.eigvalsh(0.5 * (array + np.swapaxes(array, -1, -2)))
    total = moments.sum(axis=-1, keepdims=True)
    # Strict triangle inequality up to round-off: 2·min(C eigenvalues) = I_j + I_k − I_i >= 0.
    if np.any(moments <= 0) or np.any(total - 2 * moments < -1e-9 * total):
        raise ValueError(f"sysid: field {field!r} has an inertia that is not positive definite or "
                         f"breaks the triangle inequality (principal moments {moments.tolist()})")


def _principal_forward(u):
    """(n, 3) -> (n, 3, 3): C = diag(exp u), I = diag(c₂ + c₃, c₁ + c₃, c₁ + c₂)."""
    c = jnp.exp(u)
    moments = jnp.sum(c, axis=-1, keepdims=True) - c
    return moments[..., :, None] * jnp.eye(3, dtype=u.dtype)


def _principal_inverse(inertia):
    inertia = np.asarray(inertia, dtype=np.float64)
    moments = np.diagonal(inertia, axis1=-2, axis2=-1)
    c = 0.5 * moments.sum(axis=-1, keepdims=True) - moments
    return np.log(np.maximum(c, _FLAT_FLOOR * c.max(axis=-1, keepdims=True)))


def _check_diagonal(field, value):
    _check_inertia(field, value)
    array = np.asarray(value, dtype=np.float64)
    off = array - np.diagonal(array, axis1=-2, axis2=-1)[..., None] * np.eye(3)
    if np.any(np.abs(off) > 1e-9 * np.abs(array).max()):
        raise ValueError(f"sysid: field {field!r} is not diagonal, so the 'principal' transform "
                         f"cannot represent it; use 'second_moment'")


def _softplus_inverse(value):
    value = np.asarray(value, dtype=np.float64)
    return value + np.log(-np.expm1(-value))


TRANSFORMS = {
    "identity": (Transform(lambda u: u, lambda v: np.asarray(v, dtype=np.float64), "identity"), None),
    "log": (Transform(jnp.exp, lambda v: np.log(np.asarray(v, dtype=np.float64)), "log"),
            _check_open("log", low=0.0)),
    "softplus": (Transform(jax.nn.softplus, _softplus_inverse, "softplus"), _check_open("softplus", low=0.0)),
    "clip": (Transform(lambda u: jnp.clip(u, 0.0, 1.0), lambda v: np.asarray(v, dtype=np.float64), "clip"),
             _check_open("clip", low=0.0, high=1.0, closed=True)),
    "sigmoid": (Transform(jax.nn.sigmoid, lambda v: np.log(np.asarray(v, np.float64))
                          - np.log1p(-np.asarray(v, np.float64)), "sigmoid"),
                _check_open("sigmoid", low=0.0, high=1.0)),
    "second_moment": (Transform(_second_moment_forward, _second_moment_inverse, "second_moment"),
                      _check_inertia),
    "principal": (Transform(_principal_forward, _principal_inverse, "principal"), _check_diagonal),
}

# Fields not listed use "identity" (gravity, dt, force, torque, com_offset).
DEFAULT_TRANSFORMS = {
    "mass": "log", "inertia": "second_moment",  # "log" for 2D's (n,) inertia, chosen by shape
    "friction": "log", "plane_friction": "log", "restitution": "sigmoid", "plane_restitution": "sigmoid",
    "linear_damping": "log", "angular_damping": "log", "contact_margin": "log",
    "bounce_threshold": "log", "contact_hertz": "log", "contact_damping_ratio": "log",
    "max_push_velocity": "log", "penalty_stiffness": "log", "penalty_damping": "log",
    "penalty_width": "log", "friction_velocity": "log", "dt": "log", "shape_scale": "log",
}


def _resolve_transform(name: str, params: Params, transforms) -> tuple:
    """(Transform, domain check or None) for field ``name``."""
    choice = (transforms or {}).get(name, DEFAULT_TRANSFORMS.get(name, "identity"))
    if name == "inertia" and choice in ("second_moment", "principal") and getattr(params, name).ndim == 1:
        choice = "log" if name not in (transforms or {}) else choice
    if isinstance(choice, Transform):
        return choice, None
    if choice not in TRANSFORMS:
        raise ValueError(f"sysid: unknown transform {choice!r} for field {name!r}; valid: "
                         f"{', '.join(map(repr, TRANSFORMS))} or a sysid.Transform")
    if choice in ("second_moment", "principal") and getattr(params, name).ndim != 3:
        raise ValueError(f"sysid: transform {choice!r} needs a 3D inertia-shaped field, but {name!r} "
                         f"has shape {getattr(params, name).shape}")
    return TRANSFORMS[choice]


def _check_field_name(name) -> str:
    if name in DERIVED_PARAMS:
        raise ValueError(f"sysid: Params field {name!r} is derived from the others (rollout fills it); "
                         f"fit 'inertia' instead")
    if name not in PARAM_FIELDS:
        raise ValueError(f"sysid: unknown Params field {name!r}; valid fields: {', '.join(PARAM_FIELDS)}")
    return name


def field_masks(params: Params, fields) -> dict:
    """Normalise a ``fields`` selection to ``{name: mask}``.

    Args:
        params: the Params the fields belong to.
        fields: a field name, a sequence of names, a dict ``{name: mask}``, or a
            Params-shaped pytree (e.g. ``params.replace(...)`` of bools) whose
            leaves are bools or bool arrays. A mask array selects elements:
            its shape is a leading part of the field's (``(n,)`` picks bodies,
            also of ``inertia``'s (n, 3, 3)).

    Returns:
        ``{name: True or (leading shape) bool ndarray}`` of the fitted fields only.
    """
    if isinstance(fields, str):
        fields = (fields,)
    if isinstance(fields, Params):
        fields = {name: getattr(fields, name) for name in PARAM_FIELDS}
    if isinstance(fields, Mapping):
        items = list(fields.items())
    else:
        try:
            items = [(name, True) for name in fields]
        except TypeError:
            raise ValueError(f"sysid: 'fields' must be a name, names, a dict or a Params of bools, "
                             f"got {fields!r}") from None
    masks = {}
    for name, mask in items:
        _check_field_name(name)
        value = getattr(params, name)
        mask = np.asarray(mask)
        if mask.dtype != bool:
            raise ValueError(f"sysid: the mask for field {name!r} must be bool, got dtype {mask.dtype}")
        if mask.ndim == 0:
            if bool(mask):
                masks[name] = True
            continue
        if mask.shape != value.shape[:mask.ndim]:
            raise ValueError(f"sysid: the mask for field {name!r} has shape {mask.shape}, which is not a "
                             f"leading part of the field's shape {value.shape}")
        if mask.any():
            masks[name] = mask
    if not masks:
        raise ValueError("sysid: 'fields' selects no Params field to fit")
    return masks


def to_unconstrained(params: Params, fields, transforms: Optional[Mapping] = None) -> dict:
    """Unconstrained arrays ``{name: u}`` of the selected fields.

    Args:
        params: current parameter values (the fit's starting point).
        fields: selection, as for :func:`field_masks`.
        transforms: optional ``{name: transform name or Transform}`` overriding
            :data:`DEFAULT_TRANSFORMS`.

    Returns:
        Dict of arrays in ``params``' dtype; shapes follow the transform
        ((n,) for "log" of mass, (n, 6) for "second_moment", ...).

    Raises:
        ValueError: naming the field, if a value is outside its transform's
            domain (a zero mass under "log", a restitution of 1 under "sigmoid").
    """
    unconstrained = {}
    for name in field_masks(params, fields):
        value = getattr(params, name)
        transform, check = _resolve_transform(name, params, transforms)
        if check is not None:
            check(name, value)
        unconstrained[name] = jnp.asarray(transform.inverse(np.asarray(value)), dtype=value.dtype)
    return unconstrained


def from_unconstrained(unconstrained: Mapping[str, Array], params: Params, fields=None,
                       transforms: Optional[Mapping] = None) -> Params:
    """Params with the fitted fields replaced by their transformed values.

    Traceable (jit, grad). Elements that a mask in ``fields`` leaves out keep
    their value in ``params``.

    Args:
        unconstrained: ``{name: u}`` as from :func:`to_unconstrained`.
        params: the Params supplying every other field.
        fields: the selection used for :func:`to_unconstrained`; default all of
            ``unconstrained``'s keys, whole.
        transforms: as for :func:`to_unconstrained`.

    Returns:
        ``params`` with each field of ``unconstrained`` replaced by its
        transformed value (the field's own shape, e.g. (n,) or (n, 3, 3)).
    """
    masks = field_masks(params, fields if fields is not None else tuple(unconstrained))
    changes = {}
    for name, u in unconstrained.items():
        transform, _ = _resolve_transform(name, params, transforms)
        value = transform.forward(u)
        mask = masks.get(name, True)
        if mask is not True:
            original = getattr(params, name)
            mask = jnp.asarray(mask).reshape(mask.shape + (1,) * (original.ndim - mask.ndim))
            value = jnp.where(mask, value, original)
        changes[name] = value
    return params.replace(**changes)


# --- the fit -----------------------------------------------------------------------

@dataclasses.dataclass(frozen=True)
class FitResult:
    """What :func:`fit` returns.

    Attributes:
        params: Params with the lowest loss seen.
        losses: (num_updates + 1,) numpy array; ``losses[k]`` is the loss after k
            optimiser updates (``losses[0]`` at the starting point).
        steps: optimiser updates made (fewer than asked if it stopped early).
        best_step: index into ``losses`` of ``params``.
        stopped_early: True if the ``tol`` criterion (or a non-finite loss) stopped it.
        unconstrained: ``{name: u}`` of ``params``, to resume a fit.
    """

    params: Params
    losses: np.ndarray
    steps: int
    best_step: int
    stopped_early: bool
    unconstrained: dict


def _check_observation(observed: Observation, state: State, batched: bool) -> int:
    """Validate shapes against the initial state; return the largest step index."""
    if not isinstance(observed, Observation):
        raise ValueError(f"sysid: 'observed' must be a sysid.Observation, got {type(observed).__name__}")
    steps = np.asarray(observed.steps)
    lead = state.pos.shape[:1] if batched else ()
    if steps.ndim != len(lead) + 1 or steps.shape[:len(lead)] != lead or steps.shape[-1] < 1:
        raise ValueError(f"sysid: Observation field 'steps' must have shape {lead + ('T',)} with T >= 1, "
                         f"got {steps.shape}")
    if not np.issubdtype(steps.dtype, np.integer) or np.any(steps < 1):
        raise ValueError(f"sysid: Observation field 'steps' must hold integers >= 1 (the state after k "
                         f"steps), got {steps.tolist()}")
    count, num_bodies, dim = steps.shape[-1], state.pos.shape[-2], state.pos.shape[-1]
    expected = {"pos": (num_bodies, dim), "vel": (num_bodies, dim), "mask": (num_bodies,),
                "quat": (num_bodies, 4), "angle": (num_bodies,),
                "angvel": (num_bodies, 3) if dim == 3 else (num_bodies,), "time": ()}
    if dim == 3 and observed.angle is not None:
        raise ValueError("sysid: Observation field 'angle' is 2D only; use 'quat' in 3D")
    if dim == 2 and observed.quat is not None:
        raise ValueError("sysid: Observation field 'quat' is 3D only; use 'angle' in 2D")
    present = [name for name in expected if getattr(observed, name) is not None and name not in ("mask", "time")]
    if not present:
        raise ValueError("sysid: the Observation holds no data (pos, quat/angle, vel or angvel)")
    for name, shape in expected.items():
        value = getattr(observed, name)
        if value is None:
            continue
        want = lead + (count,) + shape
        if np.shape(value) != want:
            raise ValueError(f"sysid: Observation field {name!r} must have shape {want}, got {np.shape(value)}")
        if name != "mask" and not np.all(np.isfinite(np.asarray(value))):
            raise ValueError(f"sysid: Observation field {name!r} must be finite")
    return int(steps.max())


def _check_observation_times(observed: Observation, state: State, params: Params) -> None:
    """Raise where the samples' recorded times are not the initial time plus ``steps``·dt (wrong ``every``)."""
    if observed.time is None:
        return
    dt = float(np.max(np.asarray(params.dt)))
    steps, time = np.asarray(observed.steps), np.asarray(observed.time, dtype=float)
    start = np.asarray(state.time, dtype=float)[..., None]
    expected = start + steps * dt
    wrong = np.abs(time - expected) > 0.25 * dt
    if np.any(wrong):
        first = tuple(int(i) for i in np.argwhere(wrong)[0])
        raise ValueError(
            f"sysid: Observation sample {first} is labelled step {int(steps[first])} (t = {expected[first]:.6g} s "
            f"at dt = {dt:g}) but its state was recorded at t = {time[first]:.6g} s; was observe()'s 'every' "
            f"the rollout's own every? To thin an every-step rollout, pass observe(states, steps=...)")


def _gcd(values) -> int:
    return int(np.gcd.reduce(np.asarray(values).reshape(-1)))


def make_objective(step: Callable, num_steps: int, every: int, *, weights=None, loss: Optional[Callable] = None,
                   checkpoint: Union[bool, int] = False, batched: bool = False,
                   adjoint: bool = False) -> Callable:
    """``objective(params, initial_state, observed, applied) -> ()`` for one or many trajectories.

    Rolls out ``num_steps`` steps (keeping every ``every``-th state), samples
    the rollout at ``observed.steps`` (multiples of ``every``) and scores it with
    ``loss(predicted, observed)`` (default :func:`trajectory_loss` with
    ``weights``). With ``batched``, ``initial_state``, ``observed`` and
    ``applied`` carry a leading axis B and the objective is the mean over B.

    Args:
        step: from :func:`jaxrb.make_step`.
        num_steps: steps to roll out (a multiple of ``every``, at least the
            largest observed step).
        every: rollout save interval.
        weights: :class:`LossWeights` (or dict) for the default loss.
        loss: optional ``loss(predicted, observed) -> ()`` replacing
            :func:`trajectory_loss`.
        checkpoint: passed to :func:`jaxrb.rollout`.
        adjoint: passed to :func:`jaxrb.rollout` (the hand-written reverse
            mode; the objective then has no forward mode).
        batched: average over a leading batch axis B of the trajectories.

    Returns:
        ``objective(params, initial_state, observed, applied) -> ()``, pure and
        differentiable in ``params``.
    """
    score = loss if loss is not None else (lambda predicted, observed: trajectory_loss(predicted, observed, weights))

    def one(params, initial_state, observed, applied):
        states = rollout(step, initial_state, params, num_steps, every=every, checkpoint=checkpoint, adjoint=adjoint,
                         applied=applied)
        index = observed.steps // every - 1
        predicted = jax.tree_util.tree_map(lambda a: a[index], states)
        return score(predicted, observed)

    if not batched:
        return one

    def mean_over_worlds(params, initial_state, observed, applied):
        per_world = jax.vmap(one, in_axes=(None, 0, 0, None if applied is None else 0))(
            params, initial_state, observed, applied)
        return jnp.mean(per_world)

    return mean_over_worlds


def fit(step: Callable, params: Params, initial_state: State, observed: Observation, *, fields,
        optimizer: optax.GradientTransformation, num_steps: int = 500,
        weights: Union[LossWeights, Mapping[str, float], None] = None, loss: Optional[Callable] = None,
        applied: Optional[Wrench] = None, every: Optional[int] = None, checkpoint: Union[bool, int] = False,
        transforms: Optional[Mapping] = None, tol: Optional[float] = None, patience: int = 20,
        log_every: Optional[int] = None, callback: Optional[Callable] = None,
        callback_every: int = 1, print_fn: Callable = print, adjoint: Optional[bool] = None) -> FitResult:
    """Fit the selected Params fields to observed trajectories with an optax optimiser.

    Each iteration rolls the scene out from ``initial_state``, compares it with
    ``observed`` and takes one optimiser step on the unconstrained parameters
    (see the module docs for the transforms). The update (rollout + loss +
    gradient + optimiser) is one jitted function, compiled once per call.

    Several trajectories sharing one parameter set: give ``initial_state``
    (pos (B, n, dim), ...), ``observed`` (steps (B, T), ...) and ``applied``
    with a leading batch axis B; rollouts are vmapped and the loss is their mean.

    Args:
        step: from :func:`jaxrb.make_step`.
        params: starting Params (fields not fitted keep these values).
        initial_state: State at step 0 (one world, or B worlds as above).
        observed: :class:`Observation` (batched like ``initial_state``).
        fields: what to fit: a name, names, ``{name: mask}`` or a Params of
            bools (see :func:`field_masks`). Unknown names raise ValueError.
        optimizer: any optax GradientTransformation, e.g. ``optax.adam(0.05)``.
        num_steps: maximum number of optimiser updates.
        weights: :class:`LossWeights` (or dict) for :func:`trajectory_loss`.
        loss: optional ``loss(predicted, observed) -> ()`` replacing
            :func:`trajectory_loss`; ``predicted`` is the State sampled at
            ``observed.steps`` (arrays (T, n, ...)).
        applied: optional :class:`Wrench` sequence, arrays (S, n, ...) with S >=
            the largest observed step (B, S, n, ...) when batched.
        every: rollout save interval; default the gcd of the observed steps.
        checkpoint: passed to :func:`jaxrb.rollout` (reverse mode keeps about √T step
            inputs instead of T; pays when observations are sparse, ``every`` > 1).
        transforms: ``{name: name-or-Transform}`` overriding :data:`DEFAULT_TRANSFORMS`.
        tol, patience: early stopping (module docs); ``tol=None`` runs all steps.
        log_every: print the loss every this many updates (and at the end),
            and say when the first update's compile starts and ends.
        callback: ``callback(step, loss, params)`` called every
            ``callback_every`` updates with the update count, the loss (float)
            and the Params at that point.
        callback_every: how often (in updates) ``callback`` is called.
        print_fn: where ``log_every`` lines go (e.g. ``logging.info``).
        adjoint: take gradients with :func:`jaxrb.rollout`'s hand-written
            adjoint (``adjoint=True``); None (default) does where the model
            has one (``jaxrb.adjoint.supports``: 3D semi-implicit models
            without damping, free bodies or penalty contact with spring
            friction against planes) and ``checkpoint`` is off, on every
            backend (on an H200 it took 0.6–0.7 of autodiff's time at one world:
            docs/accelerator.md). A fit only uses reverse mode, and the
            adjoint's gradients equal autodiff's to rounding.

    Returns:
        :class:`FitResult` with the best Params and the loss history.
    """
    if not hasattr(optimizer, "init") or not hasattr(optimizer, "update"):
        raise ValueError(f"sysid: 'optimizer' must be an optax GradientTransformation, got {optimizer!r}")
    for name, value, low in (("num_steps", num_steps, 0), ("patience", patience, 1),
                             ("callback_every", callback_every, 1), ("log_every", log_every, 1),
                             ("every", every, 1)):
        if value is not None and not (isinstance(value, (int, np.integer)) and not isinstance(value, bool)
                                      and value >= low):
            raise ValueError(f"sysid: {name!r} must be an integer >= {low}, got {value!r}")
    if tol is not None and not (isinstance(tol, (int, float)) and tol >= 0):
        raise ValueError(f"sysid: 'tol' must be a number >= 0 or None, got {tol!r}")
    weights = _loss_weights(weights)

    batched = initial_state.pos.ndim == params.mass.ndim + 2
    last_step = _check_observation(observed, initial_state, batched)
    _check_observation_times(observed, initial_state, params)
    if every is None:
        every = _gcd(observed.steps)
    elif np.any(np.asarray(observed.steps) % every):
        raise ValueError(f"sysid: observed 'steps' must all be multiples of every={every}")
    rollout_steps = last_step  # a multiple of every: it is one of the steps
    if applied is not None:
        length = applied.force.shape[int(batched)]
        if length < rollout_steps:
            raise ValueError(f"sysid: 'applied' covers {length} steps, but the observations reach step "
                             f"{rollout_steps}")
        applied = jax.tree_util.tree_map(
            lambda a: a[:, :rollout_steps] if batched else a[:rollout_steps], applied)

    masks = field_masks(params, fields)
    unconstrained = to_unconstrained(params, masks, transforms)
    if adjoint is None:
        model = getattr(step, "model", None)
        adjoint = model is not None and hand_written.supports(model) and not checkpoint
    objective = make_objective(step, rollout_steps, every, weights=weights, loss=loss,
                               checkpoint=checkpoint, batched=batched, adjoint=adjoint)

    def total_loss(u, base, state, obs, wrench):
        return objective(from_unconstrained(u, base, masks, transforms), state, obs, wrench)

    @jit
    def update(u, opt_state, base, state, obs, wrench):
        value, grads = jax.value_and_grad(total_loss)(u, base, state, obs, wrench)
        updates, opt_state = optimizer.update(grads, opt_state, u)
        return optax.apply_updates(u, updates), opt_state, value

    constrain = jit(lambda u, base: from_unconstrained(u, base, masks, transforms))

    opt_state = optimizer.init(unconstrained)
    losses, best_loss, best_u, best_step = [], math.inf, unconstrained, 0
    best_history = []  # best loss after each evaluation, for the tol window
    stopped_early = False
    u = unconstrained
    updates_done = 0
    for k in range(num_steps + 1):
        if k == 0 and log_every is not None:  # the first call compiles: tens of seconds for long rollouts
            print_fn(f"sysid: compiling the loss gradient of a {rollout_steps}-step rollout…")
            clock = time.perf_counter()
        # The last pass only evaluates the loss at the final parameters.
        new_u, new_opt_state, value = update(u, opt_state, params, initial_state, observed, applied)
        value = float(value)
        if k == 0 and log_every is not None:
            print_fn(f"sysid: compiled and took the first step in {time.perf_counter() - clock:.1f} s")
        losses.append(value)
        if not math.isfinite(value):
            warnings.warn(f"sysid.fit: loss became {value} after {k} updates; stopping and returning "
                          f"the best parameters so far", RuntimeWarning, stacklevel=2)
            stopped_early = True
            break
        if value < best_loss:
            best_loss, best_u, best_step = value, u, k
        best_history.append(best_loss)
        if log_every is not None and (k % log_every == 0 or k == num_steps):
            print_fn(f"sysid step {k:5d}  loss {value:.6e}")
        if callback is not None and k % callback_every == 0:
            callback(k, value, constrain(u, params))
        if (tol is not None and k >= patience
                and best_history[k - patience] - best_loss <= tol * best_history[k - patience]):
            stopped_early = k < num_steps
            break
        if k == num_steps:
            break
        u, opt_state = new_u, new_opt_state
        updates_done = k + 1
    return FitResult(params=constrain(best_u, params), losses=np.asarray(losses), steps=updates_done,
                     best_step=best_step, stopped_early=stopped_early, unconstrained=best_u)
