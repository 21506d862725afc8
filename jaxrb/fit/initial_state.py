"""Initial states of measured trajectories, estimated from their free-flight samples.

The literature's protocol (Acosta et al., RA-L 2022) simulates each
trajectory from a state estimated from its own samples *before contact*, so a
model is judged on what it predicts, not on measured states it is fed. Here:

1. :func:`free_samples` counts each trajectory's leading samples in which no
   body is within ``clearance`` of touching anything (the scene's own
   collision detection on the measured poses, velocities set to zero so the
   speculative margin does not grow).
2. :func:`estimate_initial_states` fits the state at sample 0 to those
   samples by least squares, assuming free flight: position
   p(t) = p₀ + v₀ t + ½ g t² (gravity from ``Params``), orientation
   q(t) = exp(ω t / 2) ⊗ q₀ with a constant world-frame ω. Constant ω is exact
   for a torque-free body with isotropic inertia and a good approximation over
   a short flight for any body (the cube tosses' 6-20 free samples, 40-140 ms).
   ω is the mean of the sample-to-sample rotation vectors, q₀ the sign-aligned
   mean of the samples carried back to t = 0 by the fitted ω. Measured
   velocities are not used: trackers derive them from the same poses, noisier.

Everything here runs on the host in NumPy except the contact query.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxrb.physics.collision.pairs import detect
from jaxrb.fit.measured import Trajectories
from jaxrb.model.types import Model, Params, State

#: Default clearance (m): a sample is free if nothing is closer than this to touching.
CLEARANCE = 0.005
#: Fewest free samples the fit accepts (the first two are used even if closer).
MIN_FREE_SAMPLES = 2


# Host-side quaternion helpers, (w, x, y, z), in NumPy's float64 whatever JAX's precision (the
# estimate works on raw measurements before anything is traced); jaxrb.math.quaternion has the traced ones.

def quat_multiply(a, b):
    """Hamilton product a ⊗ b of (..., 4) quaternions."""
    aw, av = a[..., :1], a[..., 1:]
    bw, bv = b[..., :1], b[..., 1:]
    return np.concatenate([aw * bw - np.sum(av * bv, -1, keepdims=True),
                           aw * bv + bw * av + np.cross(av, bv)], axis=-1)


def quat_conjugate(q):
    """The conjugate (the inverse of a unit quaternion), (..., 4)."""
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def quat_log(q):
    """Rotation vector (..., 3) of unit quaternions (..., 4), the short way round."""
    q = np.where(q[..., :1] < 0, -q, q)
    sine = np.linalg.norm(q[..., 1:], axis=-1, keepdims=True)
    angle = 2.0 * np.arctan2(sine, q[..., :1])
    scale = np.where(sine > 1e-12, angle / np.maximum(sine, 1e-300), 2.0)
    return q[..., 1:] * scale


def quat_exp(rotvec):
    """Unit quaternion (..., 4) of rotation vectors (..., 3)."""
    angle = np.linalg.norm(rotvec, axis=-1, keepdims=True)
    half = 0.5 * angle
    scale = np.where(angle > 1e-12, np.sin(half) / np.maximum(angle, 1e-300), 0.5)
    return np.concatenate([np.cos(half), rotvec * scale], axis=-1)


def free_samples(model: Model, params: Params, trajectories: Trajectories,
                 clearance: float = CLEARANCE) -> np.ndarray:
    """Number of leading samples of each trajectory before anything comes within ``clearance``.

    Args:
        model: the Model of a 3D scene with the recorded bodies (same count n).
        params: its Params.
        trajectories: K measured trajectories.
        clearance: distance (m) below which a sample counts as (nearly) in contact.

    Returns:
        (K,) int, at least :data:`MIN_FREE_SAMPLES` and at most each length.
    """
    if model.dim != 3 or model.num_bodies != trajectories.pos.shape[2]:
        raise ValueError(f"{trajectories.source}: the data has {trajectories.pos.shape[2]} bodies per sample; "
                         f"the scene is {model.dim}D with {model.num_bodies} bodies")
    if model.num_contacts == 0:
        return trajectories.length.copy()
    probe = params.replace(contact_margin=jnp.asarray(clearance, params.contact_margin.dtype))
    zeros = jnp.zeros(model.num_bodies * 3, params.mass.dtype).reshape(model.num_bodies, 3)

    @jax.jit
    def nearest(pos, quat):
        state = State(pos=pos, vel=zeros, angvel=zeros, quat=quat, angle=None, time=jnp.zeros(()))
        contacts = detect(model, probe, state)
        return jnp.any(contacts.active & (contacts.dist < clearance))

    pos = jnp.asarray(trajectories.pos, params.mass.dtype)
    quat = jnp.asarray(trajectories.quat, params.mass.dtype)
    touching = np.asarray(jax.vmap(jax.vmap(nearest))(pos, quat)) | ~trajectories.mask
    first_touch = np.where(touching.any(axis=1), touching.argmax(axis=1), trajectories.num_samples)
    return np.clip(first_touch, MIN_FREE_SAMPLES, trajectories.length)


def estimate_initial_states(trajectories: Trajectories, num_free: np.ndarray, gravity) -> dict:
    """Least-squares free-flight state at sample 0 of each trajectory (module docstring).

    Args:
        trajectories: K trajectories of n bodies.
        num_free: (K,) free samples of each (from :func:`free_samples`).
        gravity: (3,) gravitational acceleration.

    Returns:
        dict of NumPy arrays: ``pos``, ``vel``, ``angvel`` (K, n, 3) and
        ``quat`` (K, n, 4), the state at sample 0 in the world frame.
    """
    gravity = np.asarray(gravity, dtype=np.float64)
    dt = trajectories.sample_dt
    out = {name: np.empty(trajectories.pos.shape[:1] + trajectories.pos.shape[2:3] + (width,))
           for name, width in (("pos", 3), ("vel", 3), ("angvel", 3), ("quat", 4))}
    for k, count in enumerate(np.asarray(num_free)):
        count = int(count)
        time = np.arange(count) * dt
        design = np.stack([np.ones(count), time], axis=1)  # (F, 2)
        pos = trajectories.pos[k, :count] - 0.5 * time[:, None, None] ** 2 * gravity  # (F, n, 3)
        coef, *_ = np.linalg.lstsq(design, pos.reshape(count, -1), rcond=None)
        out["pos"][k] = coef[0].reshape(-1, 3)
        out["vel"][k] = coef[1].reshape(-1, 3)
        quat = trajectories.quat[k, :count]  # (F, n, 4)
        steps = quat_log(quat_multiply(quat[1:], quat_conjugate(quat[:-1])))  # (F-1, n, 3) world-frame rotation per sample
        angvel = steps.mean(axis=0) / dt
        back = quat_multiply(quat_exp(-angvel[None] * time[:, None, None]), quat)  # each sample carried to t = 0
        back = np.where(np.sum(back * back[:1], -1, keepdims=True) < 0, -back, back)
        mean = back.mean(axis=0)
        out["quat"][k] = mean / np.linalg.norm(mean, axis=-1, keepdims=True)
        out["angvel"][k] = angvel
    return out


def free_flight_residuals(trajectories: Trajectories, num_free: np.ndarray, estimate: dict, gravity) -> tuple:
    """RMS misfit of the free-flight model over each trajectory's free samples: the tracker's noise.

    Args:
        trajectories, num_free: as for :func:`estimate_initial_states`.
        estimate: its result.
        gravity: (3,) the gravity it used.

    Returns:
        (position (K,) in m, rotation (K,) in rad): per-axis RMS position
        residual and RMS rotation angle (over bodies and free samples).
    """
    gravity = np.asarray(gravity, dtype=np.float64)
    position, rotation = [], []
    for k, count in enumerate(np.asarray(num_free)):
        time = np.arange(int(count)) * trajectories.sample_dt
        pos = (estimate["pos"][k] + estimate["vel"][k] * time[:, None, None]
               + 0.5 * gravity * time[:, None, None] ** 2)
        quat = quat_multiply(quat_exp(estimate["angvel"][k] * time[:, None, None]), estimate["quat"][k])
        position.append(np.sqrt(np.mean((pos - trajectories.pos[k, :count]) ** 2)))
        angle = np.linalg.norm(quat_log(quat_multiply(quat, quat_conjugate(trajectories.quat[k, :count]))), axis=-1)
        rotation.append(np.sqrt(np.mean(angle ** 2)))
    return np.array(position), np.array(rotation)


def length_scale(trajectories: Trajectories, num_free: np.ndarray, gravity) -> float:
    """The tracker's lengths per true length, from the free-fall acceleration it measures.

    Each trajectory with at least 5 free samples gets a least-squares
    parabola with its own acceleration; the median of |a| over them, divided
    by |gravity|, is the scale (the cube tosses: 0.98, the tracker sees
    9.62 m/s² and a 1.02 % short cube at rest). Dividing positions by it
    lets the physics keep its true gravity and sizes.

    Args:
        trajectories: K trajectories.
        num_free: (K,) free samples of each.
        gravity: (3,) the model's gravitational acceleration.

    Returns:
        The scale (1.0 when no trajectory has 5 free samples or gravity is 0).
    """
    magnitude = float(np.linalg.norm(gravity))
    measured = []
    for k, count in enumerate(np.asarray(num_free)):
        if count < 5 or magnitude == 0.0:
            continue
        time = np.arange(count) * trajectories.sample_dt
        design = np.stack([np.ones(count), time, 0.5 * time ** 2], axis=1)
        coef, *_ = np.linalg.lstsq(design, trajectories.pos[k, :count].reshape(count, -1), rcond=None)
        measured.append(np.linalg.norm(coef[2].reshape(-1, 3), axis=-1).mean())
    return float(np.median(measured) / magnitude) if measured else 1.0


def initial_states(template: State, estimate: dict) -> State:
    """A batched State (leading axis K) from ``template`` with the estimated pose and velocities.

    Args:
        template: a one-world State from ``Scene.build`` (supplies the other
            fields: warm start, time, ...).
        estimate: from :func:`estimate_initial_states`.

    Returns:
        State with a leading axis K on every field.
    """
    dtype = template.pos.dtype
    count = estimate["pos"].shape[0]
    batched = jax.tree_util.tree_map(lambda a: jnp.broadcast_to(a, (count,) + jnp.shape(a)), template)
    fields = {name: jnp.asarray(estimate[name], dtype) for name in ("pos", "vel", "angvel", "quat")}
    if template.body_momentum is not None:
        raise ValueError("initial_states: integrator 'rk4_body' keeps body-frame momentum; use a contact "
                         "integrator (semi_implicit or implicit_gyro) for measured contact data")
    return batched.replace(**fields)
