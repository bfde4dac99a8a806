"""The batched Levenberg-Marquardt of identification.refinement on a problem with a known answer."""
from __future__ import annotations

import numpy as np
import pytest

from identification.refinement import refine, refine_through_gains


class _Decays:
    """Residuals of a sum of two decaying exponentials against noisy data, for a batch of x.

    A nonlinear least-squares problem with local minima, where Levenberg-Marquardt rejects
    many steps from poor starts; ``nfev`` counts the candidates simulated, as the
    library's prediction-error problems do.
    """

    def __init__(self, seed=1):
        rng = np.random.default_rng(seed)
        self.t = np.linspace(0.0, 4.0, 60)
        self.truth = np.array([2.0, 1.3, 0.7, 0.25])
        self.y = self.model(self.truth[None])[0] + 0.01 * rng.standard_normal(self.t.size)
        self.nfev = 0

    def model(self, X):
        a1, k1, a2, k2 = (X[:, i:i + 1] for i in range(4))
        return a1 * np.exp(-k1 * self.t) + a2 * np.exp(-k2 * self.t)

    def residuals(self, X):
        X = np.atleast_2d(X)
        self.nfev += X.shape[0]
        return self.model(X) - self.y


BOUNDS = np.array([[0.0, 5.0], [0.01, 5.0], [0.0, 5.0], [0.01, 5.0]])
STARTS = np.array([[4.0, 4.0, 0.1, 0.02], [0.5, 0.1, 3.0, 3.0], [1.0, 1.0, 1.0, 1.0],
                   [2.1, 1.2, 0.6, 0.3], [0.2, 4.5, 4.5, 0.05]])


def test_lazy_jacobian_gives_the_same_iterates_with_fewer_simulations():
    """Columns only for accepted steps: the same x, costs, Jacobian and residuals, bit for
    bit (the simulations of a point do not depend on its batch), fewer simulations."""
    eager, lazy = _Decays(), _Decays()
    a = refine(eager, STARTS, BOUNDS, max_iter=60, ftol=1e-12)
    b = refine(lazy, STARTS, BOUNDS, max_iter=60, ftol=1e-12, lazy_jacobian=True)
    for name in ("x", "costs", "start_costs", "jac", "residuals"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    assert (a.fun, a.nit, a.merged, a.message) == (b.fun, b.nit, b.merged, b.message)
    assert np.allclose(a.x, eager.truth, atol=0.05)  # the problem's answer
    assert a.nfev == eager.nfev and b.nfev == lazy.nfev
    assert b.nfev < a.nfev
    # the same through a continuation (here a second, tighter stage) and with one start
    c = refine_through_gains(lambda g: _Decays(), STARTS[:1], BOUNDS, (0.5, 0.1), ftol=1e-12)
    d = refine_through_gains(lambda g: _Decays(), STARTS[:1], BOUNDS, (0.5, 0.1), ftol=1e-12,
                             lazy_jacobian=True)
    np.testing.assert_array_equal(c.x, d.x)
    np.testing.assert_array_equal(c.jac, d.jac)


@pytest.mark.parametrize("lazy", [False, True])
def test_a_stop_returns_the_best_point_so_far(lazy):
    """The callback's True (a Ctrl-C in the command line) after the first start that ends:
    interrupted, the best point so far, a refinement through gains goes no further."""
    seen = []

    def callback(i, n, x, cost):
        seen.append(i)
        return True

    res = refine(_Decays(), STARTS, BOUNDS, max_iter=60, callback=callback, lazy_jacobian=lazy)
    assert res.interrupted and not res.success and len(seen) >= 1
    assert res.fun == np.min(res.costs) and np.isfinite(res.fun)
    stages = []

    def problem_at(g):
        stages.append(g)
        return _Decays()

    ref = refine_through_gains(problem_at, STARTS, BOUNDS, (0.5, 0.1, 0.05), callback=callback,
                               lazy_jacobian=lazy)
    assert ref.interrupted and stages == [0.5]


@pytest.mark.parametrize("lazy", [False, True])
def test_a_poll_stops_within_an_iteration(lazy):
    """``poll`` is asked after every iteration: its True stops at once, before any start
    has ended (the callback alone would wait for one), with the best point so far."""
    calls = []

    def poll():
        calls.append(1)
        return len(calls) >= 3

    ended = []
    res = refine(_Decays(), STARTS, BOUNDS, max_iter=60, lazy_jacobian=lazy, poll=poll,
                 callback=lambda i, n, x, c: ended.append(i) or False)
    assert res.interrupted and res.nit == 3 and len(calls) == 3 and ended == []
    assert res.fun == np.min(res.costs) < np.min(res.start_costs)
    ref = refine_through_gains(lambda g: _Decays(), STARTS, BOUNDS, (0.5, 0.1), poll=lambda: True,
                               lazy_jacobian=lazy)
    assert ref.interrupted and ref.nit == 1


@pytest.mark.parametrize("lazy", [False, True])
def test_leader_stop_ends_the_refinement_when_the_best_start_has_converged(lazy):
    """refine's ``leader_stop``: once the start of lowest cost has converged, the starts still
    iterating stop (the callback hears of each once); the answer is the full refinement's, for
    fewer simulations; one start is refined as without it."""
    full, raced = _Decays(), _Decays()
    a = refine(full, STARTS, BOUNDS, max_iter=60, ftol=1e-12, lazy_jacobian=lazy)
    heard = []
    b = refine(raced, STARTS, BOUNDS, max_iter=60, ftol=1e-12, lazy_jacobian=lazy,
               leader_stop=True, callback=lambda s, n, x, c: heard.append(s) and False)
    # the two exponentials in either order: the same minimum
    pairs = sorted(map(tuple, b.x.reshape(2, 2)))
    assert np.allclose(pairs, sorted(map(tuple, full.truth.reshape(2, 2))), atol=0.05)
    assert b.fun == pytest.approx(a.fun, rel=1e-9)
    assert b.nfev < a.nfev and b.nit < a.nit
    assert sorted(heard) == sorted(set(heard)) == list(range(1, len(STARTS) + 1))
    assert b.jac is not None and np.isfinite(b.costs).all()  # the leader's Jacobian
    # it stopped as soon as the leader converged: stopped one iteration earlier, it ends higher
    short = refine(_Decays(), STARTS, BOUNDS, max_iter=b.nit - 2, ftol=1e-12, lazy_jacobian=lazy)
    assert short.fun > b.fun
    one = refine(_Decays(), STARTS[3:4], BOUNDS, max_iter=60, ftol=1e-12, leader_stop=True)
    alone = refine(_Decays(), STARTS[3:4], BOUNDS, max_iter=60, ftol=1e-12)
    np.testing.assert_array_equal(one.x, alone.x)
    assert one.nit == alone.nit
