"""The backlash fit's basin-hopping moves (identification.flexible._hop_points)."""
from __future__ import annotations

import math

import numpy as np

from identification.flexible import _hop_points


def _box_and_point():
    k = 17
    xb = np.array([[-10.0, 10.0]] * 9 + [[3.0, 5.3]] * 2 + [[0.0, 50.0]] * 2
                  + [[0.1, 0.95]] * 2 + [[0.0, 0.01]] * 2)
    x = np.array([1.0] * 9 + [4.0, 4.5, 0.0, 2.0, 0.5, 0.5, 0.0, 2e-3])
    assert x.size == k
    return xb, x


def test_hop_points_move_one_joint_parameter_at_a_time_inside_the_box():
    xb, x = _box_and_point()
    P = _hop_points(x, xb)
    assert np.array_equal(P[0], x)
    assert np.all(P >= xb[:, 0]) and np.all(P <= xb[:, 1])
    moved = P[1:] != x
    # f and friction never move; each move changes exactly one joint parameter
    assert not moved[:, :9].any()
    assert np.all(moved.sum(axis=1) <= 1)
    # per joint: 4 stiffness, 3 backlash, 2 damping, 2 inertia-split moves
    assert P.shape[0] == 1 + 2 * 11


def test_hop_points_cover_stiffness_factors_and_move_a_zero_damping():
    xb, x = _box_and_point()
    P = _hop_points(x, xb)
    factors = sorted(10.0 ** (P[1:, 9] - x[9]))
    assert any(math.isclose(f, 2.0) for f in factors) and any(math.isclose(f, 0.5) for f in factors)
    assert np.any(P[1:, 11] > 0.0)  # joint 2's damping was 0: the x3 move adds 0.1
    # a width at 0 moves up only (the box clips -0.5 mrad to 0)
    assert set(np.round(P[1:, 15], 6)) >= {0.0, 5e-4, 1e-3}
