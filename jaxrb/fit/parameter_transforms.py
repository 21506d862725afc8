"""Parameter transforms: Params fields to unconstrained numbers and back, keeping fitted values physical.

An optimiser moves unconstrained numbers u freely; each fitted field is a
function of them that is valid for any u. :func:`field_masks` normalises a
selection of fields (names, masks of elements), :func:`to_unconstrained` and
:func:`from_unconstrained` map a Params to its u and back (traceable), and a
:class:`Transform` is one such bijection. Used by :func:`jaxrb.fit.sysid.fit` and
:func:`jaxrb.fit.fit_data.fit_measured`; ``rb.sysid`` re-exports every public name here.

The transforms (the default for each field is in :data:`DEFAULT_TRANSFORMS`):

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
"""

from __future__ import annotations

import dataclasses
from typing import Callable, Mapping, NamedTuple, Optional

import jax
import jax.numpy as jnp
import numpy as np

from jaxrb.model.types import DERIVED_PARAMS, Params

Array = jax.Array
PARAM_FIELDS = tuple(field.name for field in dataclasses.fields(Params) if field.name not in DERIVED_PARAMS)


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
                             f"start the fit from a value inside it"
                             + (f", or fit it on [0, 1] with transforms={{{field!r}: 'clip'}}" if name == "sigmoid"
                                else ""))
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
        # A field the scene lacks (joint fields of a scene without joints) is None in both.
        fields = {name: getattr(fields, name) for name in PARAM_FIELDS if getattr(fields, name) is not None}
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
    for name, mask in field_masks(params, fields).items():
        value = getattr(params, name)
        transform, check = _resolve_transform(name, params, transforms)
        array = np.asarray(value)
        if mask is not True:
            # Only the fitted elements need be in the transform's domain; the others (e.g. the
            # default restitution 0 of bodies not fitted) keep their value and get a fitted
            # element's in u, which from_unconstrained never reads.
            mask = np.reshape(mask, mask.shape + (1,) * (array.ndim - mask.ndim))
            array = np.where(mask, array, array[np.broadcast_to(mask, array.shape)][0])
        if check is not None:
            check(name, array)
        unconstrained[name] = jnp.asarray(transform.inverse(array), dtype=value.dtype)
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
