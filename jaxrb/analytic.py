"""Closed-form answers that simulations are compared with (host-side NumPy).

These are the references the tests, notebooks and benchmarks measure the
engine against: torque-free flip times from Jacobi's elliptic solution of
Euler's equations, bounce apexes, the sliding stopping distance and the
rolling acceleration on a slope. Nothing here is differentiated or jitted.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

#: Gauss–Legendre nodes for the incomplete elliptic integral; the integrand
#: 1/√(1 − k² sin²θ) is smooth on [0, φ] for k < 1, so 64 nodes reach ~1e-12
#: away from the separatrix (k → 1).
_NODES, _WEIGHTS = np.polynomial.legendre.leggauss(64)


def elliptic_k(k: float) -> float:
    """Complete elliptic integral of the first kind K(k) (modulus k, 0 ≤ k < 1).

    Args:
        k: scalar modulus.

    Returns:
        K(k) = π / (2·AGM(1, √(1 − k²))), exact to rounding.
    """
    a, b = 1.0, math.sqrt(max(1.0 - k * k, 0.0))
    for _ in range(60):
        if abs(a - b) <= 1e-16 * a:
            break
        a, b = 0.5 * (a + b), math.sqrt(a * b)
    return math.pi / (2.0 * a)


def elliptic_f(phi: float, k: float) -> float:
    """Incomplete elliptic integral of the first kind F(φ, k) for |φ| ≤ π/2.

    Args:
        phi: scalar amplitude (rad), |φ| ≤ π/2.
        k: scalar modulus, 0 ≤ k < 1.

    Returns:
        F(φ, k) = ∫₀^φ dθ / √(1 − k² sin²θ); odd in φ.
    """
    if abs(phi) > 0.5 * math.pi + 1e-12:
        raise ValueError(f"elliptic_f: 'phi' must lie in [-pi/2, pi/2], got {phi}")
    theta = 0.5 * phi * (_NODES + 1.0)
    return float(0.5 * phi * np.sum(_WEIGHTS / np.sqrt(1.0 - (k * np.sin(theta)) ** 2)))


def flip_times(inertia: Sequence[float], angvel: Sequence[float], t_end: float) -> np.ndarray:
    """Times in (0, t_end] at which the middle body-axis angular velocity changes sign.

    Torque-free motion of a rigid body (Euler's equations), solved with Jacobi
    elliptic functions (Landau & Lifshitz, Mechanics §37): with moments
    I_a < I_b < I_c and L² > 2E·I_b, ω_b = A_b·sn(τ), ω_a = A_a·cn(τ),
    ω_c = A_c·dn(τ), τ = τ₀ ± λt; for L² < 2E·I_b the roles of a and c swap.
    ω_b vanishes where sn does, at τ = 2mK. For a body spun near its middle
    axis these are the times of the intermediate-axis (Dzhanibekov) flip.

    Args:
        inertia: (3,) distinct principal moments about the body axes (kg·m²), any order.
        angvel: (3,) initial angular velocity in the body frame (rad/s).
        t_end: scalar end of the time window (s).

    Returns:
        (k,) increasing flip times (s); empty when the middle-axis component
        never changes sign in the window (or the motion is a steady spin).
    """
    inertia = np.asarray(inertia, dtype=np.float64)
    angvel = np.asarray(angvel, dtype=np.float64)
    if inertia.shape != (3,) or angvel.shape != (3,):
        raise ValueError("flip_times: 'inertia' and 'angvel' must each be 3 numbers")
    if np.any(inertia <= 0.0) or len(set(inertia.tolist())) < 3:
        raise ValueError(f"flip_times: 'inertia' must be 3 distinct positive moments, got {inertia}")
    a, b, c = np.argsort(inertia)
    two_energy = float(np.sum(inertia * angvel ** 2))
    momentum_sq = float(np.sum((inertia * angvel) ** 2))
    if momentum_sq < two_energy * inertia[b]:
        a, c = c, a  # the polhode circles the smallest axis instead: same formulas, roles swapped
    i_a, i_b, i_c = inertia[a], inertia[b], inertia[c]
    along_c = two_energy * i_c - momentum_sq   # both share the sign of (I_c − I_a)
    along_a = momentum_sq - two_energy * i_a
    if along_c * (i_c - i_a) <= 0.0 or along_a * (i_c - i_a) <= 0.0:
        return np.zeros(0)  # a steady spin about a principal axis
    amplitude_b = math.sqrt(along_c / (i_b * (i_c - i_b)))
    rate = math.sqrt((i_c - i_b) * along_a / (i_a * i_b * i_c))
    modulus_sq = (i_b - i_a) * along_c / ((i_c - i_b) * along_a)
    if not 0.0 <= modulus_sq < 1.0 - 1e-12:
        return np.zeros(0)  # on the separatrix (to rounding): the flip takes infinitely long
    modulus = math.sqrt(modulus_sq)
    quarter = elliptic_k(modulus)
    phase = elliptic_f(math.asin(float(np.clip(angvel[b] / amplitude_b, -1.0, 1.0))), modulus)
    if angvel[a] < 0.0:  # cn(τ₀) < 0: the same sn on the other half-period
        phase = math.copysign(2.0 * quarter, phase) - phase
    # Euler's equation I_b dω_b/dt = ±(I_c − I_a) ω_c ω_a (+ when (a, b, c) is a cyclic
    # order of the body axes) fixes the direction τ runs in.
    cyclic = 1.0 if (b - a) % 3 == 1 else -1.0
    direction = math.copysign(1.0, cyclic * (i_c - i_a) * angvel[c])
    speed = direction * rate
    count = int(math.ceil(rate * t_end / (2.0 * quarter))) + 2
    zeros = 2.0 * quarter * np.arange(-count, count + 1)
    times = np.sort((zeros - phase) / speed)
    return times[(times > 1e-12) & (times <= t_end)]


def bounce_apexes(height: float, restitution: float, count: int) -> np.ndarray:
    """Apex heights of a ball dropped from rest, after each of ``count`` bounces.

    Args:
        height: scalar drop height of the lowest point above the ground (m).
        restitution: scalar coefficient e in [0, 1].
        count: number of bounces.

    Returns:
        (count,) apex heights h·e^(2k), k = 1..count (m above the ground).
    """
    return height * restitution ** (2.0 * np.arange(1, count + 1))


def slide_distance(speed: float, friction: float, gravity: float = 9.81) -> float:
    """Distance a body sliding on level ground travels before Coulomb friction stops it.

    Args:
        speed: scalar initial speed (m/s).
        friction: scalar Coulomb coefficient μ > 0.
        gravity: scalar gravitational acceleration (m/s²).

    Returns:
        v² / (2 μ g) (m).
    """
    return speed ** 2 / (2.0 * friction * gravity)


def rolling_acceleration(angle: float, radius_of_gyration_sq: float, radius: float,
                         gravity: float = 9.81) -> float:
    """Acceleration of a body rolling without slipping down a slope.

    Args:
        angle: scalar slope angle (rad).
        radius_of_gyration_sq: scalar I/m about the centre (m²): 2/5·r² for a solid sphere.
        radius: scalar rolling radius (m).
        gravity: scalar gravitational acceleration (m/s²).

    Returns:
        g·sin θ / (1 + I/(m r²)) (m/s²); 5/7·g·sin θ for a solid sphere.
    """
    return gravity * math.sin(angle) / (1.0 + radius_of_gyration_sq / radius ** 2)
