"""The real-data section's peers (benchmarks.toss_peers): MuJoCo runs a toss as the publishers did.

Moved from tests/test_measured_data.py with the module it tests; skipped where
MuJoCo is not installed.
"""

import numpy as np
import pytest

from benchmarks import toss_peers
from jaxrb.fit.initial_state import quat_exp, quat_multiply

HALF_WIDTH = 0.0524  # m, the cube's half edge (benchmarks.toss_peers.CUBE_HALF_WIDTH)
DT = 1 / 148  # s, the tosses' sample spacing


def test_mujoco_peer_spins_in_the_world_frame_and_rests_on_the_table():
    """The benchmark's MuJoCo runner (benchmarks.toss_peers): a free spin follows q(t) = exp(ω t) q₀
    with ω in the world frame (MuJoCo wants it in the body frame), and a flat drop comes to rest at
    the half-width, less MuJoCo's soft-contact penetration (about 0.1 mm at the publishers' stiffness)."""
    pytest.importorskip("mujoco")
    q0 = np.array([0.5, 0.5, -0.5, 0.5])
    angvel = np.array([3.0, -7.0, 12.0])
    spin = {"pos": np.array([[[0.0, 0.0, 100.0]]]), "vel": np.zeros((1, 1, 3)), "angvel": angvel[None, None],
            "quat": q0[None, None]}
    _, quat = toss_peers.simulate_mujoco(spin, 5, DT)
    expected = quat_multiply(quat_exp(angvel * 4 * DT), q0)
    assert min(np.abs(quat[0, 4, 0] - expected).max(), np.abs(quat[0, 4, 0] + expected).max()) < 1e-6
    drop = dict(spin, pos=np.array([[[0.0, 0.0, 0.1]]]), angvel=np.zeros((1, 1, 3)),
                quat=np.array([[[1.0, 0, 0, 0]]]))
    pos, _ = toss_peers.simulate_mujoco(drop, 120, DT)
    assert pos[0, -1, 0, 2] == pytest.approx(HALF_WIDTH, abs=1e-3)
