"""benchmarks/joints_accuracy.py: the section runs, and its distances mean what they say."""

import numpy as np
import pytest

from benchmarks import joints_accuracy


def test_distances_split_lengths_and_angles():
    mujoco = pytest.importorskip("mujoco")
    model = mujoco.MjModel.from_xml_string(joints_accuracy.DOUBLE_PENDULUM_XML)
    first = np.array([[0.0, 0.0], [0.1, 0.2]])
    second = np.array([[0.0, 0.0], [0.1, 0.2 + np.radians(0.5)]])
    linear, angular = joints_accuracy.distances(model, first, second)
    assert linear == 0.0 and abs(angular - 0.5) < 1e-9


def test_the_section_runs_and_rk4_is_mujocos():
    pytest.importorskip("gymnasium")
    settings = dict(models=("inverted_pendulum",), states=1, step=1e-3, seconds=0.02, pendulum_seconds=0.02)
    text, results = joints_accuracy.joints_accuracy_section(settings, log=lambda line: None)
    assert "| inverted_pendulum" in text
    worst = results["inverted_pendulum"]
    assert max(worst["rk4"]) < 1e-9  # MuJoCo's RK4 itself
    assert np.allclose(worst["semi_implicit"], worst["MuJoCo Euler"], atol=1e-9)  # MuJoCo's Euler itself
