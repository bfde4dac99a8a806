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


def test_random_hop_points_move_the_whole_joint_block_and_repeat_with_the_seed():
    from identification.flexible import RANDOM_HOP_POINTS, _random_hop_points

    xb, x = _box_and_point()
    x = np.concatenate([x, [0.01, 0.02]])  # two unknown friction components
    xb = np.vstack([xb, [[0.0, 1.0], [0.0, 1.0]]])
    P = _random_hop_points(x, xb, np.random.default_rng(3))
    assert P.shape == (RANDOM_HOP_POINTS, x.size)
    assert np.all(P >= xb[:, 0]) and np.all(P <= xb[:, 1])
    # f and the friction stay; stiffness, damping and split of both joints move together
    assert np.array_equal(P[:, :9], np.tile(x[:9], (len(P), 1)))
    assert np.array_equal(P[:, 17:], np.tile(x[17:], (len(P), 1)))
    cols = [9, 10, 12, 13, 14]  # (joint 2's damping is 0: a move below it is clipped back)
    assert np.all((P[:, cols] != x[cols]).all(axis=1))
    assert np.any(P[:, 11] > 0.0)
    # the width of joint 3 (2 mrad, inside its box) moves in every point, by a few tenths of a mrad
    assert np.all(P[:, 16] != x[16]) and np.max(np.abs(P[:, 16] - x[16])) < 2e-3
    # the same seed gives the same moves; another seed others
    assert np.array_equal(P, _random_hop_points(x, xb, np.random.default_rng(3)))
    assert not np.array_equal(P, _random_hop_points(x, xb, np.random.default_rng(4)))


def test_the_backlash_fit_stream_is_a_child_that_leaves_the_callers_stream_alone():
    from identification.flexible import _child_rng

    g, ref = np.random.default_rng(11), np.random.default_rng(11)
    a = _child_rng(g).random(3)
    assert np.array_equal(g.random(5), ref.random(5))  # the caller's stream did not move
    assert not np.array_equal(a, np.random.default_rng(11).random(3))
    # an integer seed is a stream of its own, the same each time
    assert np.array_equal(_child_rng(5).random(3), _child_rng(5).random(3))


def test_a_larger_step_scales_the_random_moves():
    """A round without progress doubles the step (RANDOM_HOP_MAX_STEP): the same
    draws, twice as far (additive coordinates, away from the box's edges)."""
    from identification.flexible import _random_hop_points

    xb, x = _box_and_point()
    xb[9:11] = [[0.0, 9.0], [0.0, 9.0]]  # no clipping of log10 K
    P1 = _random_hop_points(x, xb, np.random.default_rng(8))
    P2 = _random_hop_points(x, xb, np.random.default_rng(8), step=2.0)
    assert np.allclose(P2[:, 9:11] - x[9:11], 2.0 * (P1[:, 9:11] - x[9:11]), rtol=1e-12, atol=1e-15)
