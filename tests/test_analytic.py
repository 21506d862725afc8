"""The closed-form references against independent numerics (scipy, a fine RK4)."""

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.special import ellipk, ellipkinc

from jaxrb import analytic


@pytest.mark.parametrize("k", [0.0, 0.3, 0.9, 0.999])
def test_elliptic_integrals_match_scipy(k):
    assert analytic.elliptic_k(k) == pytest.approx(ellipk(k * k), rel=1e-13)
    for phi in (-1.2, 0.4, 0.5 * np.pi):
        # 64 Gauss nodes: 1e-12 for moderate k; the k = 0.999, φ = π/2 peak is the hardest.
        assert analytic.elliptic_f(phi, k) == pytest.approx(np.sign(phi) * ellipkinc(abs(phi), k * k),
                                                             rel=1e-12 if k < 0.99 else 2e-3)


def _euler_flips(inertia, angvel, t_end):
    """Sign changes of the middle-axis ω of Euler's equations, integrated by scipy."""
    inertia = np.asarray(inertia)

    def rhs(_, w):
        return np.array([(inertia[1] - inertia[2]) * w[1] * w[2] / inertia[0],
                         (inertia[2] - inertia[0]) * w[2] * w[0] / inertia[1],
                         (inertia[0] - inertia[1]) * w[0] * w[1] / inertia[2]])

    middle = int(np.argsort(inertia)[1])

    def crossing(_, w):
        return w[middle]

    solution = solve_ivp(rhs, (0.0, t_end), angvel, method="DOP853", rtol=1e-12, atol=1e-12,
                         events=crossing)
    return solution.t_events[0]


def test_quoted_intermediate_axis_flip_times():
    times = analytic.flip_times((0.3, 0.35, 0.4), (0.1, 15.0, 0.1), 20.0)
    np.testing.assert_allclose(times, [3.692, 9.859, 16.027], atol=5e-4)


@pytest.mark.parametrize("seed", range(12))
def test_flip_times_match_integrated_euler_equations(seed):
    # Random moments in any axis order, random spins on both sides of the separatrix.
    rng = np.random.default_rng(seed)
    inertia = rng.uniform(0.2, 1.0, 3)
    angvel = rng.normal(size=3) * rng.uniform(0.5, 4.0, 3)
    expected = _euler_flips(inertia, angvel, 20.0)
    got = analytic.flip_times(inertia, angvel, 20.0)
    assert len(got) == len(expected)
    np.testing.assert_allclose(got, expected, atol=1e-7)


def test_steady_spin_has_no_flips_and_bad_inertia_is_rejected():
    for spin in [(0.0, 15.0, 0.0), (0.0, 0.0, 15.0), (15.0, 0.0, 0.0)]:
        assert len(analytic.flip_times((0.3, 0.35, 0.4), spin, 20.0)) == 0
    with pytest.raises(ValueError, match="distinct"):
        analytic.flip_times((0.3, 0.3, 0.4), (0.1, 15.0, 0.1), 20.0)
