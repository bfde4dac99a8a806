"""Multi-population binary genetic algorithm (the paper's GA), minimisation.

:class:`GASolver` (one generation per ``step``; :func:`run_ga` runs it to
the end) strings together the pure operators of
:mod:`identification.operators` (ranking, SUS, single-point crossover,
mutation, reinsertion, migration; their module docstring gives the design
choices the paper leaves open) into the Sheffield GA Toolbox scheme the paper
uses (Chipperfield, Fleming, Pohlheim & Fonseca, 1994).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Optional, Sequence, Union

import numpy as np

from .operators import (
    TOPOLOGIES,
    BinaryEncoding,
    RngLike,
    as_rng,
    crossover_single_point,
    migrate,
    mutate,
    n_migrants,
    n_offspring,
    ranking,
    reinsert,
    sus,
    worst_key,
)

__all__ = [
    "PAPER_GA",
    "BinaryEncoding",
    "ranking",
    "sus",
    "crossover_single_point",
    "mutate",
    "reinsert",
    "migrate",
    "n_offspring",
    "n_migrants",
    "GAState",
    "GAResult",
    "GASolver",
    "run_ga",
]

#: The paper's GA settings (section 4): 4 subpopulations of 20, 40
#: generations, SP 2.0, single-point crossover 0.6, generation gap 0.94,
#: complete-net migration at rate 0.3.
PAPER_GA = dict(n_subpops=4, n_ind=20, n_gen=40, sp=2.0, p_xover=0.6, ggap=0.94,
                migration_rate=0.3, migration_interval=5, bits=20)


@dataclass(frozen=True)
class GAState:
    """What :func:`run_ga` passes to ``callback`` after every generation.

    Attributes
    ----------
    generation : int
        Generations completed.
    x : ndarray, shape (n,)
        Best point evaluated so far.
    fun : float
        Its objective.
    mean : float
        Mean of the finite objectives in the population.
    nfev : int
        Objective evaluations so far.
    """

    generation: int
    x: np.ndarray
    fun: float
    mean: float
    nfev: int


@dataclass
class GAResult:
    """Outcome of :func:`run_ga` (scipy ``OptimizeResult`` vocabulary).

    Attributes
    ----------
    x : ndarray, shape (n,)
        Best point evaluated (decoded).
    fun : float
        Its objective value.
    nfev : int
        Objective evaluations.
    nit : int
        Generations completed.
    success : bool
        False when stopped early (``interrupted``).
    message : str
    population : ndarray, shape (n_subpops * n_ind, n)
        Final population, subpopulation after subpopulation.
    population_energies : ndarray, shape (n_subpops * n_ind,)
        Objective values of the final population (scipy's name).
    history : dict of ndarray, each shape (nit + 1,)
        ``'best'``: best objective in the population after each generation
        (index 0: initial population); ``'best_so_far'``: best ever
        evaluated (equal to ``'best'`` with elitism, i.e. ggap < 1);
        ``'mean'``: mean of the finite objectives in the population (a
        few penalised candidates dominate it); ``'median'``: their median;
        ``'nfev'``: cumulative evaluation count.
    interrupted : bool
        True when stopped early by ``callback`` or KeyboardInterrupt.
    """

    x: np.ndarray
    fun: float
    nfev: int = 0
    nit: int = 0
    success: bool = True
    message: str = ""
    population: Optional[np.ndarray] = None
    population_energies: Optional[np.ndarray] = None
    history: dict = field(default_factory=dict)
    interrupted: bool = False


def _evaluate(evaluate, X: np.ndarray, cap=None) -> np.ndarray:
    y = np.asarray(evaluate(X) if cap is None else evaluate(X, cap=cap), dtype=float)
    if y.size != X.shape[0]:
        raise ValueError(f"evaluate returned {y.size} values for {X.shape[0]} points")
    return worst_key(y.reshape(X.shape[0]))


def _cap(objv: np.ndarray, early_stop: Optional[float]) -> Optional[float]:
    """Early-termination cap: a quantile of the population's finite objectives."""
    if early_stop is None:
        return None
    finite = objv[np.isfinite(objv)]
    return float(np.quantile(finite, float(early_stop))) if finite.size else None


def _finite_median(objv) -> float:
    """Median of the finite objectives (nan if none)."""
    v = np.asarray(objv, dtype=float).ravel()
    v = v[np.isfinite(v)]
    return float(np.median(v)) if v.size else float("nan")


def _finite_mean(o: np.ndarray) -> float:
    f = o[np.isfinite(o)]
    return float(f.mean()) if f.size else float("nan")


class GASolver:
    """The paper's multi-population GA as an object that can be stepped.

    In the manner of scipy's ``DifferentialEvolutionSolver``: build it with
    the objective, the box and the settings of :func:`run_ga` (the same
    names and defaults), then either :meth:`solve` (what :func:`run_ga`
    does) or advance it yourself, one generation per :meth:`step` (or
    ``for state in solver``), reading :attr:`x`, :attr:`fun`, :attr:`nfev`,
    :attr:`generation` and :attr:`population` on the way, and take
    :meth:`result` when you stop.  Stepping it ``n_gen`` times gives
    exactly :func:`run_ga`'s result (the same random stream).

    Parameters
    ----------
    evaluate : callable
        ``evaluate(X) -> y`` with ``X`` of shape (m, n) and ``y`` (m,).
        Called once for the initial population (``n_subpops * n_ind``
        rows) and once per generation with all offspring stacked
        (``n_subpops * n_offspring`` rows: 80 then 76 at the defaults).
        Non-finite values count as worst.
    bounds : array_like, shape (n, 2)
        Search box, see :class:`BinaryEncoding`.
    n_subpops, n_ind, n_gen : int
        Subpopulations (4), individuals per subpopulation (20),
        generations (40).
    bits : int or sequence of int
        Bits per gene (20).
    sp : float
        Selection pressure of the linear ranking (2.0).
    p_xover : float
        Single-point crossover probability (0.6).
    p_mut : float or None
        Bit-flip probability (None: 0.7 / L).
    ggap : float
        Generation gap, in (0, 1] (0.94).
    migration_rate : float
        Fraction migrating (0.3).
    migration_interval : int
        Generations between migrations (5); 0 disables migration.
    rng : numpy.random.Generator, int or None
        Passed to :func:`numpy.random.default_rng`; the same seed gives a
        bit-identical result.
    initial : array_like, shape (k, n) or (n,), optional
        Points seeded (encoded to the nearest code, clipped to the box)
        into the initial population: point ``i`` replaces individual
        ``i // n_subpops`` of subpopulation ``i % n_subpops``.
    gray : bool
        Gray-coded chromosomes (False).
    topology, immigrants : str
        See :func:`migrate` (``'complete'``, ``'uniform'``).
    early_stop : float in [0, 1] or None
        Early termination of hopeless offspring.  When given, ``evaluate``
        is called as ``evaluate(X, cap=c)`` with ``c`` the ``early_stop``
        quantile of the current population's finite objective values (1.0:
        the worst individual).  ``evaluate`` may then stop computing a point
        as soon as its value is known to exceed ``c`` and return any larger
        value for it (the output error returns its running sum extrapolated
        to the whole log).  Such offspring still enter the population, since
        reinsertion replaces the worst parents unconditionally; only their
        ranks among themselves are approximate.  None (default) evaluates
        every point completely.

    Raises
    ------
    ValueError
        On a setting out of its range or malformed initial points.
    """

    def __init__(self, evaluate, bounds, *, n_subpops=4, n_ind=20, n_gen=40, bits=20, sp=2.0,
                 p_xover=0.6, p_mut=None, ggap=0.94, migration_rate=0.3, migration_interval=5,
                 rng=None, initial=None, gray=False, topology="complete", immigrants="uniform",
                 early_stop=None):
        n_subpops, n_ind, n_gen = int(n_subpops), int(n_ind), int(n_gen)
        if n_subpops < 1 or n_ind < 2 or n_gen < 0:
            raise ValueError(f"need n_subpops >= 1, n_ind >= 2, n_gen >= 0, "
                             f"got {n_subpops}, {n_ind}, {n_gen}")
        if not (0.0 < ggap <= 1.0):
            raise ValueError(f"generation gap must be in (0, 1], got {ggap}")
        if not (1.0 <= sp <= 2.0):
            raise ValueError(f"selection pressure sp must be in [1, 2], got {sp}")
        if not (0.0 <= p_xover <= 1.0):
            raise ValueError(f"crossover probability must be in [0, 1], got {p_xover}")
        if p_mut is not None and not (0.0 <= p_mut <= 1.0):
            raise ValueError(f"mutation probability must be in [0, 1], got {p_mut}")
        if not (0.0 <= migration_rate <= 1.0):
            raise ValueError(f"migration rate must be in [0, 1], got {migration_rate}")
        if int(migration_interval) < 0:
            raise ValueError(f"migration interval must be >= 0, got {migration_interval}")
        if topology not in TOPOLOGIES or immigrants not in ("uniform", "best"):
            raise ValueError(f"bad topology {topology!r} or immigrants {immigrants!r}")
        if early_stop is not None and not (0.0 <= float(early_stop) <= 1.0):
            raise ValueError(f"early_stop must be a quantile in [0, 1] or None, got {early_stop}")
        self.evaluate = evaluate
        self.n_subpops, self.n_ind, self.n_gen = n_subpops, n_ind, n_gen
        self.sp, self.p_xover, self.p_mut, self.ggap = sp, p_xover, p_mut, ggap
        self.migration_rate, self.migration_interval = migration_rate, int(migration_interval)
        self.topology, self.immigrants, self.early_stop = topology, immigrants, early_stop
        self.rng = as_rng(rng)
        self.encoding = BinaryEncoding(bounds, bits=bits, gray=gray)
        L, n = self.encoding.length, self.encoding.n_genes
        n_total = n_subpops * n_ind
        self._n_sel = n_offspring(n_ind, ggap)
        chrom = self.encoding.random(n_total, self.rng)
        if initial is not None:
            x0 = np.atleast_2d(np.asarray(initial, dtype=float))
            if x0.ndim != 2 or x0.shape[1] != n:
                raise ValueError(f"initial points must have shape (k, {n}), got {np.shape(initial)}")
            if x0.shape[0] > n_total:
                raise ValueError(f"{x0.shape[0]} initial points exceed the population of {n_total}")
            i = np.arange(x0.shape[0])
            chrom[(i % n_subpops) * n_ind + i // n_subpops] = self.encoding.encode(x0)
        self._chrom0 = chrom.reshape(n_subpops, n_ind, L)
        # State lives in tuples replaced by single assignments, so that a
        # KeyboardInterrupt arriving anywhere leaves a consistent "best so far".
        self._pop = None  # (chromosomes (n_subpops, n_ind, L), objectives (n_subpops, n_ind))
        self._best = None  # (fun, x, nfev)
        self._hist = []  # (best, best so far, mean, nfev, median) per generation

    # ------------------------------------------------------------------ state
    def init_population(self) -> None:
        """Evaluate the initial population (once; :meth:`step` calls it)."""
        if self._pop is not None:
            return
        enc, L = self.encoding, self.encoding.length
        chrom = self._chrom0
        objv = _evaluate(self.evaluate, enc.decode(chrom.reshape(-1, L))).reshape(
            self.n_subpops, self.n_ind)
        ib = int(np.argmin(objv))
        self._best = (float(objv.reshape(-1)[ib]), enc.decode(chrom.reshape(-1, L)[ib]),
                      objv.size)
        self._hist = [(float(objv.min()), self._best[0], _finite_mean(objv), objv.size,
                       _finite_median(objv))]
        self._pop = (chrom, objv)

    @property
    def generation(self) -> int:
        """Generations completed (0 before the first :meth:`step`)."""
        return max(len(self._hist) - 1, 0)

    @property
    def x(self) -> np.ndarray | None:
        """Best point evaluated so far, shape (n,); None before any evaluation."""
        return None if self._best is None else np.asarray(self._best[1], dtype=float).copy()

    @property
    def fun(self) -> float:
        """Its objective; inf before any evaluation."""
        return np.inf if self._best is None else self._best[0]

    @property
    def nfev(self) -> int:
        """Objective evaluations so far."""
        return 0 if self._best is None else int(self._best[2])

    @property
    def population(self) -> np.ndarray:
        """The current population, decoded, shape (n_subpops * n_ind, n)."""
        chrom = self._chrom0 if self._pop is None else self._pop[0]
        return self.encoding.decode(chrom.reshape(-1, self.encoding.length))

    @property
    def population_energies(self) -> np.ndarray | None:
        """Objectives of :attr:`population`, shape (n_subpops * n_ind,); None before
        :meth:`init_population` (reading a property never runs the objective)."""
        return None if self._pop is None else self._pop[1].reshape(-1).copy()

    # ------------------------------------------------------------------- steps
    def step(self) -> GAState:
        """One generation: selection, crossover, mutation, evaluation, reinsertion, migration.

        Returns
        -------
        GAState
            After the generation.

        Raises
        ------
        StopIteration
            When ``n_gen`` generations are done.
        """
        self.init_population()
        gen = self.generation + 1
        if gen > self.n_gen:
            raise StopIteration
        enc, L, rng = self.encoding, self.encoding.length, self.rng
        chrom, objv = self._pop
        off = np.empty((self.n_subpops, self._n_sel, L), dtype=chrom.dtype)
        for s in range(self.n_subpops):
            sel = chrom[s, sus(ranking(objv[s], self.sp), self._n_sel, rng)]
            sel = crossover_single_point(sel, self.p_xover, rng)
            off[s] = mutate(sel, self.p_mut, rng)
        X_off = enc.decode(off.reshape(-1, L))
        objv_off = _evaluate(self.evaluate, X_off, _cap(objv, self.early_stop))
        j = int(np.argmin(objv_off))
        best = self._best
        n_eval = best[2] + X_off.shape[0]
        if objv_off[j] < best[0]:
            best = (float(objv_off[j]), X_off[j].copy(), n_eval)
        else:
            best = (best[0], best[1], n_eval)
        objv_off = objv_off.reshape(self.n_subpops, self._n_sel)
        new_chrom = np.empty_like(chrom)
        new_objv = np.empty_like(objv)
        for s in range(self.n_subpops):
            new_chrom[s], new_objv[s] = reinsert(chrom[s], objv[s], off[s], objv_off[s])
        if (self.migration_interval and self.n_subpops > 1
                and gen % self.migration_interval == 0 and gen < self.n_gen):
            new_chrom, new_objv = migrate(new_chrom, new_objv, self.migration_rate, rng,
                                          topology=self.topology, immigrants=self.immigrants)
        self._best = best
        self._pop = (new_chrom, new_objv)
        self._hist.append((float(new_objv.min()), best[0], _finite_mean(new_objv), n_eval,
                           _finite_median(new_objv)))
        return GAState(generation=gen, x=best[1].copy(), fun=best[0], mean=self._hist[-1][2],
                       nfev=n_eval)

    def __iter__(self):
        return self

    def __next__(self) -> GAState:
        return self.step()

    def solve(self, callback=None, progress=False) -> GAResult:
        """Run the remaining generations (what :func:`run_ga` does).

        Parameters
        ----------
        callback : callable, optional
            ``callback(GAState) -> bool`` after every generation; True stops.
        progress : bool
            A tqdm bar per generation (only when stderr is a terminal).

        Returns
        -------
        GAResult
            ``interrupted=True`` when stopped by the callback or a
            KeyboardInterrupt (an interrupt during the initial population
            propagates: there is no "so far").
        """
        from tqdm.auto import tqdm

        self.init_population()
        interrupted, message = False, None
        # disable=None: tqdm switches itself off when stderr is not a terminal (no
        # carriage-return flood in a log file)
        bar = tqdm(total=self.n_gen - self.generation, desc="GA", unit="gen",
                   disable=None if progress else True, leave=False)
        try:
            bar.set_postfix(best=f"{self._best[0]:.6g}")
            while self.generation < self.n_gen:
                try:
                    state = self.step()
                    bar.update(1)
                    bar.set_postfix(best=f"{state.fun:.6g}")
                    if callback is not None and callback(state):
                        interrupted = True
                        message = f"stopped by callback after generation {state.generation}"
                        break
                except KeyboardInterrupt:
                    interrupted = True
                    message = (f"interrupted (KeyboardInterrupt) after generation "
                               f"{self.generation}")
                    break
        finally:
            bar.close()
        return self.result(interrupted=interrupted, message=message)

    def result(self, interrupted=False, message=None) -> GAResult:
        """The :class:`GAResult` of the generations so far.

        Parameters
        ----------
        interrupted : bool
            Mark the result as stopped early (``success`` False).
        message : str, optional
            Default: ``"completed N generations"``.
        """
        self.init_population()
        chrom, objv = self._pop
        h = np.asarray(self._hist, dtype=float).reshape(-1, 5)
        return GAResult(
            x=np.asarray(self._best[1], dtype=float),
            fun=self._best[0],
            nfev=int(self._best[2]),
            nit=len(self._hist) - 1,
            success=not interrupted,
            message=message or f"completed {self.n_gen} generations",
            population=self.encoding.decode(chrom.reshape(-1, self.encoding.length)),
            population_energies=objv.reshape(-1).copy(),
            history={
                "best": h[:, 0].copy(),
                "best_so_far": h[:, 1].copy(),
                "mean": h[:, 2].copy(),
                "nfev": h[:, 3].astype(np.int64),
                "median": h[:, 4].copy(),
            },
            interrupted=interrupted,
        )


def run_ga(
    evaluate: Callable[[np.ndarray], np.ndarray],
    bounds,
    *,
    n_subpops: int = 4,
    n_ind: int = 20,
    n_gen: int = 40,
    bits: Union[int, Sequence[int]] = 20,
    sp: float = 2.0,
    p_xover: float = 0.6,
    p_mut: Optional[float] = None,
    ggap: float = 0.94,
    migration_rate: float = 0.3,
    migration_interval: int = 5,
    rng: RngLike = None,
    callback: Optional[Callable[[GAState], bool]] = None,
    progress: bool = False,
    initial=None,
    gray: bool = False,
    topology: str = "complete",
    immigrants: str = "uniform",
    early_stop: Optional[float] = None,
) -> GAResult:
    """Minimise ``evaluate`` over a box with the paper's multi-population GA.

    Per generation and subpopulation: :func:`ranking` (``sp``),
    :func:`sus` of ``n_offspring(n_ind, ggap)`` parents,
    :func:`crossover_single_point` (``p_xover``), :func:`mutate`
    (``p_mut``), then one batched objective call for all subpopulations'
    offspring, :func:`reinsert` per subpopulation, and :func:`migrate`
    after every ``migration_interval``-th generation (not after the last).

    Parameters
    ----------
    evaluate, bounds, n_subpops, n_ind, n_gen, bits, sp, p_xover, p_mut, ggap, migration_rate, migration_interval, rng, initial, gray, topology, immigrants, early_stop
        As :class:`GASolver` (the same names and defaults: 4 subpopulations
        of 20, 40 generations, 20 bits per gene, ranking pressure 2.0,
        crossover 0.6, mutation 0.7 / L, generation gap 0.94, 30 % migrating
        every 5 generations).
    callback : callable, optional
        ``callback(GAState) -> bool`` after every generation; True stops.
    progress : bool
        Show a tqdm bar per generation with the best objective (only when
        stderr is a terminal).

    Returns
    -------
    GAResult
        A KeyboardInterrupt raised in ``evaluate`` or the loop, or a
        callback returning True, ends the search early: the best so far is
        returned with ``interrupted=True``.  (An interrupt while the
        initial population is evaluated propagates: there is no "so far".)
    """
    solver = GASolver(evaluate, bounds, n_subpops=n_subpops, n_ind=n_ind, n_gen=n_gen, bits=bits,
                      sp=sp, p_xover=p_xover, p_mut=p_mut, ggap=ggap,
                      migration_rate=migration_rate, migration_interval=migration_interval,
                      rng=rng, initial=initial, gray=gray, topology=topology,
                      immigrants=immigrants, early_stop=early_stop)
    return solver.solve(callback=callback, progress=progress)
