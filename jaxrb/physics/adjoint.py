"""Hand-written reverse mode of rollouts: ``rb.rollout(..., adjoint=True)``.

Autodiff's reverse mode of a rollout recomputes each step in the backward
loop and transposes it. On XLA's CPU backend that transpose fuses badly
(each cotangent component in its own kernel, re-deriving what it shares with
the others), so for the two model families below a hand-written adjoint is
kept; autodiff of the same step measured 1.83× slower on the penalty box
drop and 1.60× on the free tumble (one world, 1 000 steps):

* free bodies: :mod:`jaxrb.physics.free_body_adjoint`;
* bodies against planes with penalty contact and spring friction, built on
  the free-body substep: :mod:`jaxrb.physics.plane_penalty_adjoint`.

This module picks between them; each is tested against autodiff.
"""

from __future__ import annotations

from typing import Callable, Optional

from jaxrb.physics import free_body_adjoint

from jaxrb.physics import plane_penalty_adjoint
from jaxrb.model.types import Model, Params, State, Wrench


def supports(model: Model) -> bool:
    """Whether ``model``'s rollouts have a hand-written adjoint.

    Args:
        model: a Model from ``Scene.build``.

    Returns:
        True for 3D semi-implicit models without damping or joints that are
        free bodies or bodies against planes with penalty contact and spring friction.
    """
    if model.joints is not None:
        return False
    return free_body_adjoint.supports(model) or plane_penalty_adjoint.supports(model)


def rollout(step: Callable, state: State, params: Params, num_steps: int, every: int,
            applied: Optional[Wrench]) -> State:
    """``rb.rollout(..., adjoint=True)``: the same States, with a hand-written adjoint as reverse mode.

    Args:
        step: from :func:`jaxrb.make_step` of a model :func:`supports` accepts.
        state: initial State.
        params: Params with ``inv_inertia`` filled (``rb.rollout`` does it).
        num_steps: steps, a multiple of ``every``.
        every: keep every ``every``-th state.
        applied: None or a Wrench with a leading axis (num_steps, ...).

    Returns:
        The stacked States (num_steps // every, ...): bit for bit
        ``rb.rollout``'s for free bodies, to float rounding for penalty
        contact. Forward mode raises (``jax.custom_vjp``).
    """
    module = free_body_adjoint if free_body_adjoint.supports(step.model) else plane_penalty_adjoint
    return module.rollout(step, state, params, num_steps, every, applied)
