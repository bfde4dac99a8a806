"""Tests of the paper's multi-population GA (identification.ga)."""
import numpy as np
import pytest

from identification.ga import (
    BinaryEncoding,
    GAResult,
    GAState,
    crossover_single_point,
    migrate,
    mutate,
    n_migrants,
    n_offspring,
    ranking,
    reinsert,
    run_ga,
    sus,
)

BOUNDS9 = np.array([[-5.0, 5.0]] * 9)


def sphere(X):
    return np.sum((X - 1.0) ** 2, axis=1)


# ----------------------------------------------------------------- encoding
@pytest.mark.parametrize("gray", [False, True])
def test_encode_decode_round_trip_within_resolution(gray):
    rng = np.random.default_rng(1)
    bounds = np.array([[-1.0, 3.0], [0.0, 1e-3], [-200.0, -100.0]])
    enc = BinaryEncoding(bounds, bits=[20, 12, 7], gray=gray)
    assert enc.length == 39
    x = rng.uniform(bounds[:, 0], bounds[:, 1], size=(500, 3))
    chrom = enc.encode(x)
    assert chrom.shape == (500, 39) and chrom.dtype == np.uint8
    assert np.all(np.abs(enc.decode(chrom) - x) <= enc.resolution / 2 * (1 + 1e-9))
    # codes are fixed points of decode -> encode
    c = enc.random(50, rng)
    np.testing.assert_array_equal(enc.encode(enc.decode(c)), c)


def test_decode_extremes_and_binary_values():
    enc = BinaryEncoding([[2.0, 4.0], [-1.0, 1.0]], bits=3)
    chrom = np.array([[0, 0, 0, 1, 1, 1], [0, 0, 1, 1, 0, 0]], dtype=np.uint8)
    np.testing.assert_allclose(enc.decode(chrom), [[2.0, 1.0], [2.0 + 2 / 7, -1.0 + 2 * 4 / 7]])
    np.testing.assert_allclose(enc.resolution, [2 / 7, 2 / 7])
    np.testing.assert_allclose(enc.decode(chrom[0]), [2.0, 1.0])  # 1-D input


def test_gray_code_neighbours_differ_by_one_bit():
    enc = BinaryEncoding([[0.0, 255.0]], bits=8, gray=True)
    x = np.arange(256.0)[:, None]
    c = enc.encode(x)
    np.testing.assert_allclose(enc.decode(c), x)
    assert np.all(np.sum(c[1:] != c[:-1], axis=1) == 1)


def test_encode_clips_to_bounds():
    enc = BinaryEncoding([[0.0, 1.0]], bits=10)
    np.testing.assert_allclose(enc.decode(enc.encode([[-3.0], [7.0]])), [[0.0], [1.0]])


@pytest.mark.parametrize("bounds", [
    [[0.0, np.nan]], [[0.0, np.inf]], [[1.0, 1.0]], [[2.0, 1.0]], [0.0, 1.0], [[0.0, 1.0, 2.0]],
])
def test_bad_bounds_raise_one_line_value_error(bounds):
    with pytest.raises(ValueError) as e:
        BinaryEncoding(bounds)
    assert "\n" not in str(e.value)


# ------------------------------------------------------------------ ranking
def test_ranking_sp2_best_2_worst_0_linear():
    objv = np.array([5.0, 1.0, 3.0, 4.0, 2.0])
    fit = ranking(objv, 2.0)
    np.testing.assert_allclose(fit, [0.0, 2.0, 1.0, 0.5, 1.5])
    assert fit.mean() == pytest.approx(1.0)


def test_ranking_other_sp_and_bounds():
    fit = ranking(np.arange(11.0), 1.5)
    assert fit[0] == pytest.approx(1.5) and fit[-1] == pytest.approx(0.5)
    np.testing.assert_allclose(np.diff(fit), -0.1)
    np.testing.assert_allclose(ranking([3.0, 1.0, 2.0], 1.0), 1.0)
    for sp in (0.9, 2.1):
        with pytest.raises(ValueError):
            ranking([1.0, 2.0], sp)


def test_ranking_ties_get_average_and_nonfinite_is_worst():
    fit = ranking([1.0, 2.0, 2.0, 3.0], 2.0)  # positions 4, 2.5, 2.5, 1
    np.testing.assert_allclose(fit, [2.0, 1.0, 1.0, 0.0])
    fit = ranking([np.nan, 1.0, np.inf, 2.0, -np.inf], 2.0)
    # -inf is non-finite too: worst. The 3 non-finite share positions 1..3.
    np.testing.assert_allclose(fit, [0.5, 2.0, 0.5, 1.5, 0.5])
    # row-wise on a (n_sub, n_ind) array
    np.testing.assert_allclose(ranking([[1.0, 2.0], [4.0, 3.0]]), [[2.0, 0.0], [0.0, 2.0]])


# ---------------------------------------------------------------------- SUS
def test_sus_counts_are_floor_or_ceil_of_expected():
    rng = np.random.default_rng(0)
    fit = ranking(rng.random(20))
    for n_sel in (19, 7, 40):
        expected = n_sel * fit / fit.sum()
        for _ in range(200):
            idx = sus(fit, n_sel, rng)
            assert idx.shape == (n_sel,)
            counts = np.bincount(idx, minlength=fit.size)
            assert np.all(counts >= np.floor(expected - 1e-9))
            assert np.all(counts <= np.ceil(expected + 1e-9))


def test_sus_zero_fitness_never_selected_and_order_shuffled():
    rng = np.random.default_rng(3)
    fit = np.array([0.0, 1.0, 0.0, 3.0])
    idx = sus(fit, 1000, rng)
    assert set(np.unique(idx)) == {1, 3}
    assert np.count_nonzero(idx == 3) == 750
    assert not np.all(np.diff(idx) >= 0)  # not in cumulative (sorted) order


def test_sus_is_unbiased():
    rng = np.random.default_rng(5)
    fit = np.array([0.3, 0.2, 0.5])
    counts = sum(np.bincount(sus(fit, 1, rng), minlength=3) for _ in range(4000))
    np.testing.assert_allclose(counts / 4000, fit, atol=0.03)


# ---------------------------------------------------------------- crossover
def test_crossover_preserves_bits_per_column_pair():
    rng = np.random.default_rng(0)
    chrom = rng.integers(0, 2, size=(19, 30), dtype=np.uint8)
    out = crossover_single_point(chrom, 1.0, rng)
    assert out.shape == chrom.shape and out.dtype == chrom.dtype
    a, b, oa, ob = chrom[0:18:2], chrom[1:18:2], out[0:18:2], out[1:18:2]
    np.testing.assert_array_equal(a.astype(int) + b, oa.astype(int) + ob)
    np.testing.assert_array_equal(out[18], chrom[18])  # odd row passes
    # each child is a head of one parent and the tail of the other, cut in 1..L-1
    for pa, pb, ca in zip(a, b, oa):
        cut = [k for k in range(1, 30)
               if np.array_equal(ca, np.concatenate((pa[:k], pb[k:])))]
        assert cut or np.array_equal(pa, pb)


def test_crossover_p0_unchanged_and_input_not_modified():
    rng = np.random.default_rng(1)
    chrom = rng.integers(0, 2, size=(10, 16), dtype=np.uint8)
    keep = chrom.copy()
    np.testing.assert_array_equal(crossover_single_point(chrom, 0.0, rng), chrom)
    crossover_single_point(chrom, 1.0, rng)
    np.testing.assert_array_equal(chrom, keep)


def test_crossover_rate():
    rng = np.random.default_rng(2)
    a = np.zeros((2000, 40), dtype=np.uint8)
    a[1::2] = 1
    out = crossover_single_point(a, 0.6, rng)
    crossed = np.any(out[0::2] != 0, axis=1)
    assert crossed.mean() == pytest.approx(0.6, abs=0.05)


# ----------------------------------------------------------------- mutation
def test_mutation_rate_near_p_and_default():
    rng = np.random.default_rng(0)
    chrom = rng.integers(0, 2, size=(400, 180), dtype=np.uint8)
    out = mutate(chrom, 0.05, rng)
    assert out.dtype == np.uint8 and set(np.unique(out)) <= {0, 1}
    n = chrom.size
    rate = np.mean(out != chrom)
    assert abs(rate - 0.05) < 4 * np.sqrt(0.05 * 0.95 / n)
    rate = np.mean(mutate(chrom, None, rng) != chrom)  # 0.7 / L
    p = 0.7 / 180
    assert abs(rate - p) < 4 * np.sqrt(p * (1 - p) / n)
    np.testing.assert_array_equal(mutate(chrom, 0.0, rng), chrom)


# --------------------------------------------------------------- reinsertion
def test_reinsert_keeps_best_parent_and_size():
    rng = np.random.default_rng(0)
    parents = rng.integers(0, 2, size=(20, 8), dtype=np.uint8)
    pobj = rng.random(20)
    off = rng.integers(0, 2, size=(19, 8), dtype=np.uint8)
    oobj = rng.random(19) + 5.0  # all worse than every parent
    chrom, objv = reinsert(parents, pobj, off, oobj)
    assert chrom.shape == (20, 8) and objv.shape == (20,)
    ib = np.argmin(pobj)
    np.testing.assert_array_equal(chrom[ib], parents[ib])
    assert objv[ib] == pobj[ib]
    assert sorted(objv[np.arange(20) != ib]) == sorted(oobj)


def test_reinsert_replaces_worst_nonfinite_first():
    parents = np.arange(5, dtype=np.uint8)[:, None]
    pobj = np.array([1.0, np.nan, 3.0, 0.5, 2.0])
    chrom, objv = reinsert(parents, pobj, np.array([[9], [8]], np.uint8), [0.1, 0.2])
    # the two worst (nan, 3.0) are replaced; best parents stay in place
    np.testing.assert_array_equal(objv[[0, 3, 4]], [1.0, 0.5, 2.0])
    np.testing.assert_array_equal(np.sort(objv[[1, 2]]), [0.1, 0.2])
    np.testing.assert_array_equal(chrom[[0, 3, 4], 0], [0, 3, 4])
    assert {tuple(r) for r in chrom[[1, 2]]} == {(9,), (8,)}
    assert all(objv[i] == {9: 0.1, 8: 0.2}[chrom[i, 0]] for i in (1, 2))
    # more offspring than parents: the best offspring fill the population
    chrom, objv = reinsert(parents[:2], [1.0, 2.0], np.array([[7], [8], [9]], np.uint8),
                           [3.0, 0.0, 1.0])
    assert sorted(objv) == [0.0, 1.0]


def test_sizes_of_offspring_and_migrants():
    assert n_offspring(20, 0.94) == 19
    assert n_offspring(20, 1.0) == 20
    assert n_offspring(4, 0.1) == 2
    assert n_migrants(20, 0.3) == 6
    assert n_migrants(20, 1.0) == 19


# ----------------------------------------------------------------- migration
@pytest.mark.parametrize("topology", ["complete", "neighbourhood", "ring"])
@pytest.mark.parametrize("immigrants", ["uniform", "best"])
def test_migration_keeps_sizes_and_global_best(topology, immigrants):
    rng = np.random.default_rng(0)
    chroms = rng.integers(0, 2, size=(4, 20, 12), dtype=np.uint8)
    objv = rng.random((4, 20))
    objv[2, 7] = -1.0  # global best
    objv[1, 3] = np.nan
    c, o = migrate(list(chroms), objv, 0.3, rng, topology=topology, immigrants=immigrants)
    assert c.shape == chroms.shape and o.shape == objv.shape
    assert o[2, 7] == -1.0
    np.testing.assert_array_equal(c[2, 7], chroms[2, 7])
    assert not np.isnan(o[1, 3])  # the worst was replaced
    for i in range(4):
        # 6 worst replaced, 14 best stay in place
        stay = np.argsort(objv[i] if i != 1 else np.nan_to_num(objv[i], nan=np.inf))[:14]
        np.testing.assert_array_equal(o[i, stay], objv[i, stay])
        changed = np.setdiff1d(np.arange(20), stay)
        for j in changed:  # each immigrant comes from another subpopulation's best 6
            src = [k for k in range(4) if k != i
                   and any(np.array_equal(c[i, j], chroms[k, m])
                           for m in np.argsort(np.nan_to_num(objv[k], nan=np.inf))[:6])]
            assert src


def test_migration_complete_best_takes_best_of_others():
    chroms = np.arange(3 * 4, dtype=np.uint8).reshape(3, 4, 1)
    objv = np.arange(12.0).reshape(3, 4)  # subpop 0 holds the best overall
    c, o = migrate(chroms, objv, 0.5, 0, immigrants="best")
    # k = 2: subpop 0 draws from the pool {4, 5, 8, 9} of the others -> 4, 5
    np.testing.assert_array_equal(o[0], [0, 1, 4, 5])
    np.testing.assert_array_equal(o[1], [4, 5, 0, 1])
    np.testing.assert_array_equal(o[2], [8, 9, 0, 1])
    np.testing.assert_array_equal(c[..., 0], o.astype(np.uint8))


def test_migration_single_subpop_or_zero_rate_is_noop():
    chroms = np.ones((1, 5, 3), np.uint8)
    objv = np.arange(5.0)[None]
    c, o = migrate(chroms, objv, 0.3, 0)
    np.testing.assert_array_equal(c, chroms)
    c, o = migrate(np.ones((3, 5, 3), np.uint8), np.zeros((3, 5)), 0.0, 0)
    np.testing.assert_array_equal(o, 0.0)


# ------------------------------------------------------------------- run_ga
def test_run_ga_reaches_near_minimum_and_beats_initial():
    res = run_ga(sphere, BOUNDS9, rng=0)
    assert isinstance(res, GAResult)
    assert res.nit == 40 and not res.interrupted
    assert res.fun < 0.05 * res.history["best"][0]
    assert res.fun < 2.0
    assert res.x.shape == (9,)
    assert sphere(res.x[None])[0] == pytest.approx(res.fun)
    for key in ("best", "best_so_far", "mean", "nfev"):
        assert res.history[key].shape == (41,)
    assert np.all(np.diff(res.history["best"]) <= 0)  # elitism
    assert res.history["nfev"][-1] == res.nfev == 80 + 40 * 76
    assert res.population.shape == (80, 9) and res.population_energies.shape == (80,)
    np.testing.assert_allclose(sphere(res.population), res.population_energies)
    # longer run with Gray coding (no Hamming cliffs): close to the optimum at (1, ..., 1)
    res = run_ga(sphere, BOUNDS9, rng=1, n_gen=150, gray=True)
    assert res.fun < 1e-3
    np.testing.assert_allclose(res.x, 1.0, atol=0.03)


def test_run_ga_rosenbrock_improves():
    def rosen(X):
        return np.sum(100 * (X[:, 1:] - X[:, :-1] ** 2) ** 2 + (1 - X[:, :-1]) ** 2, axis=1)
    res = run_ga(rosen, np.array([[-2.0, 2.0]] * 9), rng=0, n_gen=60)
    assert res.fun < 0.1 * res.history["best"][0]


def test_the_solver_steps_to_run_gas_result():
    """GASolver, stepped by hand, is run_ga: the same stream, the same result."""
    from identification.ga import GASolver

    ref = run_ga(sphere, BOUNDS9, rng=3, n_gen=12, migration_interval=4)
    solver = GASolver(sphere, BOUNDS9, rng=3, n_gen=12, migration_interval=4)
    assert solver.generation == 0 and solver.nfev == 0
    # reading the state never runs the objective
    assert solver.x is None and solver.fun == np.inf and solver.population_energies is None
    assert solver.population.shape == (80, 9) and solver.nfev == 0
    states = []
    for state in solver:  # one generation per step, until n_gen
        assert isinstance(state, GAState) and state.generation == solver.generation
        assert solver.fun == state.fun and solver.nfev == state.nfev
        states.append(state)
    assert len(states) == 12
    with pytest.raises(StopIteration):
        solver.step()
    res = solver.result()
    np.testing.assert_array_equal(res.x, ref.x)
    np.testing.assert_array_equal(res.population, ref.population)
    for k in ref.history:
        np.testing.assert_array_equal(res.history[k], ref.history[k])
    assert (res.fun, res.nfev, res.nit, res.message) == (ref.fun, ref.nfev, ref.nit, ref.message)
    # solve() continues from where the steps left off
    half = GASolver(sphere, BOUNDS9, rng=3, n_gen=12, migration_interval=4)
    for _ in range(5):
        half.step()
    np.testing.assert_array_equal(half.solve().x, ref.x)


def test_run_ga_reproducible():
    a = run_ga(sphere, BOUNDS9, rng=7, n_gen=10)
    b = run_ga(sphere, BOUNDS9, rng=np.random.default_rng(7), n_gen=10)
    c = run_ga(sphere, BOUNDS9, rng=8, n_gen=10)
    np.testing.assert_array_equal(a.x, b.x)
    np.testing.assert_array_equal(a.population, b.population)
    for k in a.history:
        np.testing.assert_array_equal(a.history[k], b.history[k])
    assert a.fun == b.fun
    assert not np.array_equal(a.population, c.population)
    assert a.fun != c.fun


def test_evaluate_called_once_per_generation_with_stacked_batches():
    sizes = []

    def f(X):
        sizes.append(X.shape)
        return sphere(X)

    res = run_ga(f, BOUNDS9, rng=0)
    assert len(sizes) == 41
    assert sizes[0] == (80, 9) and all(s == (76, 9) for s in sizes[1:])
    assert res.nfev == sum(s[0] for s in sizes)


def test_callback_stops_early():
    states = []

    def cb(state):
        states.append(state)
        return state.generation == 3

    res = run_ga(sphere, BOUNDS9, rng=0, callback=cb)
    assert [s.generation for s in states] == [1, 2, 3]
    assert isinstance(states[0], GAState)
    assert res.interrupted and res.nit == 3
    assert "callback" in res.message
    assert res.history["best"].shape == (4,)
    assert states[-1].fun == res.fun
    assert states[-1].nfev == res.nfev == 80 + 3 * 76
    assert np.isfinite(states[-1].mean)


def test_keyboard_interrupt_returns_best_so_far():
    calls = []

    def f(X):
        calls.append(1)
        if len(calls) == 6:
            raise KeyboardInterrupt
        return sphere(X)

    res = run_ga(f, BOUNDS9, rng=0)
    assert res.interrupted and res.nit == 4
    assert "KeyboardInterrupt" in res.message
    assert res.nfev == 80 + 4 * 76
    assert res.fun == res.history["best_so_far"][-1]
    assert res.fun == pytest.approx(sphere(res.x[None])[0])
    assert res.population.shape == (80, 9)


def test_nonfinite_objectives_are_worst():
    def f(X):
        y = sphere(X)
        y[X[:, 0] > 0] = np.nan  # half the box is infeasible
        return y

    res = run_ga(f, BOUNDS9, rng=0, n_gen=15)
    assert np.isfinite(res.fun) and res.x[0] <= 0
    assert np.isfinite(res.history["mean"]).all()


def test_initial_points_are_seeded():
    x0 = np.full((1, 9), 1.0)  # the optimum
    res = run_ga(sphere, BOUNDS9, rng=0, n_gen=0, initial=x0)
    assert res.fun < 9 * (10 / 2**20) ** 2
    assert res.nit == 0 and res.history["best"].shape == (1,)
    with pytest.raises(ValueError):
        run_ga(sphere, BOUNDS9, rng=0, n_gen=0, initial=np.zeros((81, 9)))
    with pytest.raises(ValueError):
        run_ga(sphere, BOUNDS9, rng=0, n_gen=0, initial=np.zeros((2, 8)))


def test_general_settings_and_validation():
    bounds = np.array([[0.0, 2.0]] * 3)
    sizes = []

    def f(X):
        sizes.append(len(X))
        return sphere(X)

    res = run_ga(f, bounds, n_subpops=5, n_ind=10, n_gen=6, bits=12, ggap=0.8,
                 migration_interval=2, gray=True, rng=0, progress=False)
    assert sizes == [50] + [40] * 6 and res.population.shape == (50, 3)
    for kw in ({"sp": 2.5}, {"ggap": 0.0}, {"p_xover": 1.5}, {"n_ind": 1},
               {"migration_rate": -0.1}, {"topology": "star"}):
        with pytest.raises(ValueError):
            run_ga(sphere, bounds, rng=0, n_gen=1, **kw)
    with pytest.raises(ValueError):
        run_ga(lambda X: np.zeros(3), bounds, rng=0)


def test_early_stop_passes_the_population_quantile_as_cap():
    """With early_stop the evaluator gets the cap; values above it still enter the population."""
    caps = []

    def evaluate(X, cap=None):
        caps.append(cap)
        y = np.sum(X**2, axis=1)
        if cap is not None:  # an evaluator that stops: any value above the cap
            y = np.where(y > cap, cap * 10.0, y)
        return y

    bounds = [[-1.0, 1.0]] * 3
    res = run_ga(evaluate, bounds, n_gen=5, rng=0, early_stop=1.0)
    assert caps[0] is None and all(c is not None and c > 0 for c in caps[1:])
    assert len(caps) == 6
    assert res.fun < 0.05
    for q in (-0.1, 1.5):
        with pytest.raises(ValueError, match="early_stop"):
            run_ga(evaluate, bounds, n_gen=1, rng=0, early_stop=q)


def test_average_ranks_match_scipy_rankdata():
    """The GA's own tie-averaging ranks equal scipy.stats.rankdata(method='average')."""
    from scipy.stats import rankdata

    from identification.operators import _average_ranks

    rng = np.random.default_rng(0)
    for _ in range(100):
        a = rng.integers(0, 5, size=(3, int(rng.integers(1, 12)))).astype(float)
        a[a == 4] = np.inf
        np.testing.assert_array_equal(_average_ranks(-a), rankdata(-a, method="average", axis=-1))
