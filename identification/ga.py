"""Multi-population binary genetic algorithm (the paper's GA), minimisation.

A re-implementation, from its documented behaviour, of the scheme of the
Sheffield Genetic Algorithm Toolbox for MATLAB (Chipperfield, Fleming,
Pohlheim & Fonseca, 1994) that the paper uses; no toolbox code is copied.
One generation of each subpopulation is::

    ranking (linear, SP 2.0) -> select (SUS, generation gap 0.94)
    -> recombin (single-point crossover, p 0.6) -> mut (bit flip, 0.7/L)
    -> objective -> reins (fitness-based: offspring replace the worst)

and every ``migration_interval`` generations the subpopulations exchange
individuals over a complete net (``migrate``, rate 0.3).

Every operator is a small pure function of its inputs and a
:class:`numpy.random.Generator`; :func:`run_ga` strings them together.

Design choices (the paper leaves these open)
--------------------------------------------
* **Precision.**  20 bits per gene: the resolution is ``range / (2**20 - 1)``,
  about 1e-6 of the search range.  The identification targets a few per cent
  of each parameter, and the output error is measured in whole encoder
  pulses, so the quantisation of the chromosome is 3-4 orders of magnitude
  below anything the objective can resolve.  More bits would only dilute the
  mutation rate (0.7 / L per bit) over bits that do not matter.
* **Migration interval 5.**  With 20 individuals, linear ranking at SP 2 and
  a generation gap of 0.94, a subpopulation is taken over by its best
  individual within roughly ``log2(20)`` ~ 4-5 generations.  Migrating every
  5 generations lets each island converge on its own basin first (diversity
  between islands), then spreads good building blocks before they are lost:
  7 exchanges in the paper's 40 generations (after generations 5, 10, ... 35;
  a migration after the last generation would not be evaluated further).
* **Immigrant choice.**  The toolbox's complete net builds, for each
  subpopulation, a pool of the emigrants of all *other* subpopulations and
  draws the immigrants from that pool uniformly at random; they replace the
  worst individuals of the receiver.  Emigrants are the best individuals of
  each subpopulation (the toolbox's fitness-based selection, ``Select = 1``).
  ``immigrants='best'`` takes the best of the pool instead.
* **Ties and non-finite objectives.**  NaN/inf objectives are treated as
  ``+inf`` (worst) everywhere.  Tied objectives share the average of their
  ranks (hence equal fitness); sorts elsewhere are stable, so ties are
  broken by position, deterministically.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Optional, Sequence, Union

import numpy as np
from scipy.stats import rankdata

__all__ = [
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
    "run_ga",
]

RngLike = Union[np.random.Generator, int, None]


def _rng(rng: RngLike) -> np.random.Generator:
    return rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)


def _round_half_up(x: float) -> int:
    """Round like MATLAB's ``floor(x + .5)`` (Python's round() is banker's)."""
    return int(math.floor(x + 0.5))


def _worst_key(objv) -> np.ndarray:
    """Objective values as float with every non-finite value mapped to +inf."""
    o = np.asarray(objv, dtype=float)
    return np.where(np.isfinite(o), o, np.inf)


# --------------------------------------------------------------------------
# Encoding
# --------------------------------------------------------------------------
class BinaryEncoding:
    """Fixed-point binary chromosome over box bounds (toolbox ``crtbp``/``bs2rv``).

    Gene ``g`` occupies ``bits[g]`` consecutive bits, most significant bit
    first.  Its integer value ``k`` in ``0 .. 2**bits[g] - 1`` maps linearly
    onto the closed interval ``[lo_g, hi_g]`` (both bounds included, as
    ``bs2rv`` with its default FieldD)::

        x_g = lo_g + k * (hi_g - lo_g) / (2**bits[g] - 1)

    Parameters
    ----------
    bounds : array_like, shape (n, 2)
        ``(low, high)`` per gene; finite, ``low < high``.
    bits : int or sequence of int, default 20
        Bits per gene (1..52), one value for all genes or one per gene.
        20 bits give a resolution of ``range / 1048575`` ~ 1e-6 of the
        range, far below the accuracy an identification can reach.
    gray : bool, default False
        Gray-coded genes instead of standard binary.

    Attributes
    ----------
    n_genes : int
    length : int
        Chromosome length ``L = sum(bits)``.
    lower, upper : ndarray, shape (n,)
    resolution : ndarray, shape (n,)
        Step between adjacent codes, ``(hi - lo) / (2**bits - 1)``.

    Raises
    ------
    ValueError
        Bounds not of shape (n, 2), not finite, or ``low >= high``; bits
        not integers in 1..52.
    """

    def __init__(self, bounds, bits: Union[int, Sequence[int]] = 20, gray: bool = False):
        b = np.asarray(bounds, dtype=float)
        if b.ndim != 2 or b.shape[1] != 2 or b.shape[0] < 1:
            raise ValueError(f"bounds must have shape (n, 2), got {b.shape}")
        if not np.all(np.isfinite(b)):
            bad = int(np.flatnonzero(~np.all(np.isfinite(b), axis=1))[0])
            raise ValueError(f"bounds of gene {bad} are not finite: {b[bad].tolist()}")
        if np.any(b[:, 0] >= b[:, 1]):
            bad = int(np.flatnonzero(b[:, 0] >= b[:, 1])[0])
            raise ValueError(
                f"bounds of gene {bad} need low < high, got [{b[bad, 0]:g}, {b[bad, 1]:g}]"
            )
        n = b.shape[0]
        bits_arr = np.broadcast_to(np.asarray(bits), (n,)) if np.ndim(bits) == 0 else np.asarray(bits)
        if bits_arr.shape != (n,):
            raise ValueError(f"bits must be an int or have length {n}, got shape {bits_arr.shape}")
        if not np.all(np.equal(np.mod(bits_arr, 1), 0)) or np.any(bits_arr < 1) or np.any(bits_arr > 52):
            raise ValueError(f"bits must be integers in 1..52, got {bits_arr.tolist()}")
        self.bits = bits_arr.astype(np.int64).copy()
        self.gray = bool(gray)
        self.lower = b[:, 0].copy()
        self.upper = b[:, 1].copy()
        self.n_genes = n
        self.length = int(self.bits.sum())
        self._levels = 2.0 ** self.bits - 1.0  # largest integer per gene
        self.resolution = (self.upper - self.lower) / self._levels
        # gene index and place value of every bit (MSB first within a gene)
        self._gene_of_bit = np.repeat(np.arange(n), self.bits)
        starts = np.concatenate(([0], np.cumsum(self.bits)[:-1]))
        self._start = starts
        pos_in_gene = np.arange(self.length) - starts[self._gene_of_bit]
        self._shift = (self.bits[self._gene_of_bit] - 1 - pos_in_gene).astype(np.int64)
        place = np.ldexp(1.0, self._shift)  # exact powers of two
        self._weights = np.zeros((self.length, n))
        self._weights[np.arange(self.length), self._gene_of_bit] = place

    def __repr__(self) -> str:
        return (f"BinaryEncoding(n_genes={self.n_genes}, length={self.length}, "
                f"gray={self.gray})")

    def _check_chrom(self, chrom) -> np.ndarray:
        c = np.asarray(chrom)
        if c.shape[-1] != self.length:
            raise ValueError(f"chromosomes must have {self.length} bits, got {c.shape[-1]}")
        return c

    def decode_int(self, chrom) -> np.ndarray:
        """Integer value of every gene.

        Parameters
        ----------
        chrom : array_like of {0, 1}, shape (m, L) or (L,)

        Returns
        -------
        ndarray of float64 (exact integers), shape (m, n) or (n,)
        """
        c = self._check_chrom(chrom).astype(np.int64) & 1
        if self.gray:
            # binary bit i = XOR of the Gray bits 0..i of the same gene:
            # a running sum restarted at every gene start, modulo 2
            cs = np.cumsum(c, axis=-1)
            before = np.concatenate(
                (np.zeros(c.shape[:-1] + (1,), dtype=np.int64), cs[..., :-1]), axis=-1
            )
            cs = cs - before[..., self._start][..., self._gene_of_bit]
            c = cs & 1
        return c.astype(float) @ self._weights

    def decode(self, chrom) -> np.ndarray:
        """Phenotypes of binary chromosomes (toolbox ``bs2rv``).

        Parameters
        ----------
        chrom : array_like of {0, 1} (e.g. uint8), shape (m, L) or (L,)

        Returns
        -------
        x : ndarray of float64, shape (m, n) or (n,)
            ``lo + k * resolution`` per gene; all zeros decode to ``lo``,
            all ones to ``hi``.
        """
        k = self.decode_int(chrom)
        return self.lower + k * self.resolution

    def encode(self, x) -> np.ndarray:
        """Chromosomes of the codes nearest to points ``x``.

        Parameters
        ----------
        x : array_like, shape (m, n) or (n,)
            Points; values outside the bounds are clipped onto them.

        Returns
        -------
        chrom : ndarray of uint8, shape (m, L) or (L,)
            ``decode(encode(x))`` is within ``resolution / 2`` of the clipped x.

        Raises
        ------
        ValueError
            Wrong last dimension or non-finite values.
        """
        xa = np.asarray(x, dtype=float)
        if xa.shape[-1:] != (self.n_genes,):
            raise ValueError(f"points must have {self.n_genes} coordinates, got shape {xa.shape}")
        if not np.all(np.isfinite(xa)):
            raise ValueError("points to encode must be finite")
        xc = np.clip(xa, self.lower, self.upper)
        k = np.rint((xc - self.lower) / self.resolution)
        k = np.clip(k, 0.0, self._levels).astype(np.int64)
        if self.gray:
            k = k ^ (k >> 1)
        return ((k[..., self._gene_of_bit] >> self._shift) & 1).astype(np.uint8)

    def random(self, m: int, rng: RngLike = None) -> np.ndarray:
        """``m`` uniformly random chromosomes (toolbox ``crtbp``).

        Returns
        -------
        ndarray of uint8, shape (m, L)
        """
        return _rng(rng).integers(0, 2, size=(int(m), self.length), dtype=np.uint8)


# --------------------------------------------------------------------------
# Operators
# --------------------------------------------------------------------------
def ranking(objv, sp: float = 2.0) -> np.ndarray:
    """Linear rank-based fitness for minimisation (toolbox ``ranking``).

    Individuals are sorted by objective; with position ``r`` (1 = worst,
    ``N`` = best) the fitness is::

        F(r) = 2 - sp + 2 (sp - 1) (r - 1) / (N - 1)

    so the best gets ``sp`` and the worst ``2 - sp`` (2.0 and 0.0 at
    ``sp = 2``) and the mean fitness is 1.  Tied objectives get the average
    of their positions, hence equal fitness.  Non-finite objectives rank as
    worst (tied among themselves).

    Parameters
    ----------
    objv : array_like, shape (N,) or (..., N)
        Objective values; ranked along the last axis (one subpopulation per
        row).
    sp : float, default 2.0
        Selection pressure, in [1, 2].

    Returns
    -------
    fitness : ndarray of float, same shape as ``objv``
        A single individual (N = 1) gets fitness 1.

    Raises
    ------
    ValueError
        ``sp`` outside [1, 2].
    """
    if not (1.0 <= sp <= 2.0):
        raise ValueError(f"selection pressure sp must be in [1, 2], got {sp}")
    key = _worst_key(objv)
    n = key.shape[-1] if key.ndim else 1
    if key.ndim == 0 or n == 1:
        return np.ones_like(key, dtype=float)
    # rank 1 = largest objective (worst); inf ties share the lowest ranks
    pos = rankdata(-key, method="average", axis=-1)
    return 2.0 - sp + 2.0 * (sp - 1.0) * (pos - 1.0) / (n - 1.0)


def sus(fitness, n_sel: int, rng: RngLike = None) -> np.ndarray:
    """Stochastic universal sampling (Baker 1987; toolbox ``sus``).

    ``n_sel`` equally spaced pointers, with one uniform random offset, are
    laid over the cumulative fitness; individual ``i`` is selected once per
    pointer in its segment, i.e. ``floor`` or ``ceil`` of
    ``n_sel * fitness[i] / sum(fitness)`` times (minimum spread).  As in the
    toolbox, the selected indices are returned in random order so that
    consecutive pairs for crossover are random.

    Parameters
    ----------
    fitness : array_like, shape (N,)
        Non-negative fitness values (e.g. from :func:`ranking`).  If they
        sum to zero every individual is equally likely.
    n_sel : int
        Number of individuals to select (>= 0).
    rng : numpy.random.Generator, int or None

    Returns
    -------
    idx : ndarray of int64, shape (n_sel,)
        Indices into ``fitness``, shuffled.

    Raises
    ------
    ValueError
        Not 1-D, empty, negative or non-finite fitness, negative ``n_sel``.
    """
    rng = _rng(rng)
    f = np.asarray(fitness, dtype=float)
    if f.ndim != 1 or f.size == 0:
        raise ValueError(f"fitness must be a non-empty 1-D array, got shape {f.shape}")
    if not np.all(np.isfinite(f)) or np.any(f < 0):
        raise ValueError("fitness must be finite and non-negative")
    n_sel = int(n_sel)
    if n_sel < 0:
        raise ValueError(f"n_sel must be >= 0, got {n_sel}")
    total = f.sum()
    if total <= 0:
        f = np.ones_like(f)
        total = float(f.size)
    cum = np.cumsum(f)
    step = total / max(n_sel, 1)
    pointers = rng.random() * step + step * np.arange(n_sel)
    idx = np.searchsorted(cum, pointers, side="right")
    idx = np.minimum(idx, f.size - 1)  # guard against rounding at the top end
    return rng.permutation(idx).astype(np.int64)


def crossover_single_point(chrom, p: float = 0.6, rng: RngLike = None) -> np.ndarray:
    """Single-point crossover of consecutive pairs (toolbox ``xovsp``).

    Rows ``(0, 1), (2, 3), ...`` are mated; each pair recombines with
    probability ``p`` by swapping the tails after one uniform cut point in
    ``1 .. L-1`` (so both children differ from the parents' split).  An
    odd last row passes through unchanged, as does everything if ``L < 2``.

    Parameters
    ----------
    chrom : array_like, shape (m, L)
        Binary chromosomes, mates in consecutive rows.
    p : float, default 0.6
        Crossover probability per pair, in [0, 1].
    rng : numpy.random.Generator, int or None

    Returns
    -------
    ndarray, shape (m, L), same dtype
        A new array; the input is not modified.  Column by column, each
        pair keeps its multiset of bits.
    """
    if not (0.0 <= p <= 1.0):
        raise ValueError(f"crossover probability must be in [0, 1], got {p}")
    rng = _rng(rng)
    c = np.array(chrom, copy=True)
    if c.ndim != 2:
        raise ValueError(f"chromosomes must be 2-D (m, L), got shape {c.shape}")
    m, L = c.shape
    n_pairs = m // 2
    if n_pairs == 0 or L < 2:
        return c
    do = rng.random(n_pairs) < p
    cut = rng.integers(1, L, size=n_pairs)
    swap = (np.arange(L)[None, :] >= cut[:, None]) & do[:, None]
    a = c[0:2 * n_pairs:2].copy()
    b = c[1:2 * n_pairs:2].copy()
    c[0:2 * n_pairs:2] = np.where(swap, b, a)
    c[1:2 * n_pairs:2] = np.where(swap, a, b)
    return c


def mutate(chrom, p: Optional[float] = None, rng: RngLike = None) -> np.ndarray:
    """Bit-flip mutation (toolbox ``mut``).

    Every bit flips independently with probability ``p``.

    Parameters
    ----------
    chrom : array_like of {0, 1}, shape (m, L)
    p : float or None
        Flip probability per bit, in [0, 1].  None: the toolbox default
        ``0.7 / L`` (about 0.7 flipped bits per chromosome).
    rng : numpy.random.Generator, int or None

    Returns
    -------
    ndarray, shape (m, L), same dtype (a new array)
    """
    c = np.asarray(chrom)
    L = c.shape[-1]
    if p is None:
        p = 0.7 / L
    if not (0.0 <= p <= 1.0):
        raise ValueError(f"mutation probability must be in [0, 1], got {p}")
    flip = _rng(rng).random(c.shape) < p
    return (c ^ flip.astype(c.dtype)).astype(c.dtype, copy=False)


def reinsert(parents, parent_objv, offspring, offspring_objv):
    """Fitness-based reinsertion (toolbox ``reins`` with ``InsOpt = [1, 1]``).

    The offspring replace the worst parents; the population size is
    unchanged.  With fewer offspring than parents (generation gap < 1) the
    best ``N - m`` parents survive (elitism).  If there are more offspring
    than parents, only the best ``N`` offspring are inserted.  Non-finite
    objectives count as worst; ties are broken by position (stable sort).

    Parameters
    ----------
    parents : array_like, shape (N, L)
    parent_objv : array_like, shape (N,)
    offspring : array_like, shape (m, L)
    offspring_objv : array_like, shape (m,)

    Returns
    -------
    chrom : ndarray, shape (N, L)
        New population: the replaced rows hold offspring, the others the
        surviving parents at their old positions.
    objv : ndarray of float, shape (N,)
    """
    chrom = np.array(parents, copy=True)
    objv = np.array(parent_objv, dtype=float, copy=True)
    off = np.asarray(offspring)
    off_objv = np.asarray(offspring_objv, dtype=float)
    if chrom.shape[0] != objv.shape[0] or off.shape[0] != off_objv.shape[0]:
        raise ValueError("chromosomes and objective values must have the same length")
    n_ins = min(off.shape[0], chrom.shape[0])
    if n_ins == 0:
        return chrom, objv
    if off.shape[0] > n_ins:
        keep = np.argsort(_worst_key(off_objv), kind="stable")[:n_ins]
        off, off_objv = off[keep], off_objv[keep]
    worst = np.argsort(_worst_key(objv), kind="stable")[chrom.shape[0] - n_ins:]
    chrom[worst] = off
    objv[worst] = off_objv
    return chrom, objv


def n_offspring(n_ind: int, ggap: float) -> int:
    """Offspring per subpopulation: ``max(floor(ggap * n_ind + 0.5), 2)``, at most ``n_ind``.

    As the toolbox's ``select``: 19 for 20 individuals at ggap 0.94.
    """
    return min(max(_round_half_up(ggap * n_ind), 2), int(n_ind))


def n_migrants(n_ind: int, rate: float) -> int:
    """Migrants per subpopulation: ``floor(rate * n_ind + 0.5)``, capped at ``n_ind - 1``.

    6 for 20 individuals at rate 0.3.  The cap keeps every subpopulation's
    best individual at home.
    """
    return max(0, min(_round_half_up(rate * n_ind), int(n_ind) - 1))


_TOPOLOGIES = ("complete", "neighbourhood", "ring")


def migrate(chroms, objv, rate: float = 0.3, rng: RngLike = None,
            topology: str = "complete", immigrants: str = "uniform"):
    """Migration between subpopulations (toolbox ``migrate``).

    Each subpopulation emits its ``k = n_migrants(n_ind, rate)`` best
    individuals (fitness-based emigration).  Subpopulation ``i`` builds a
    pool from the emigrants of its source subpopulations:

    * ``'complete'``: all other subpopulations (complete net);
    * ``'neighbourhood'``: ``i - 1`` and ``i + 1`` (cyclic);
    * ``'ring'``: ``i - 1`` (cyclic).

    From the pool it takes ``k`` immigrants, uniformly at random without
    replacement (``immigrants='uniform'``, the toolbox's pool draw) or the
    best ``k`` (``'best'``), and they replace its ``k`` worst individuals.
    All emigrants are chosen before any replacement (synchronous exchange).
    Population sizes are unchanged, and since ``k < n_ind`` the best
    individual of every subpopulation, hence the global best, survives.

    Parameters
    ----------
    chroms : array_like or list of arrays, shape (n_sub, n_ind, L)
    objv : array_like, shape (n_sub, n_ind)
    rate : float, default 0.3
        Fraction of each subpopulation that migrates, in [0, 1].
    rng : numpy.random.Generator, int or None
    topology : {'complete', 'neighbourhood', 'ring'}
    immigrants : {'uniform', 'best'}

    Returns
    -------
    chroms : ndarray, shape (n_sub, n_ind, L)
    objv : ndarray of float, shape (n_sub, n_ind)
        New arrays; the inputs are not modified.
    """
    if topology not in _TOPOLOGIES:
        raise ValueError(f"topology must be one of {_TOPOLOGIES}, got {topology!r}")
    if immigrants not in ("uniform", "best"):
        raise ValueError(f"immigrants must be 'uniform' or 'best', got {immigrants!r}")
    if not (0.0 <= rate <= 1.0):
        raise ValueError(f"migration rate must be in [0, 1], got {rate}")
    rng = _rng(rng)
    c = np.array(chroms, copy=True)
    o = np.array(objv, dtype=float, copy=True)
    if c.ndim != 3 or o.shape != c.shape[:2]:
        raise ValueError(f"need chroms (n_sub, n_ind, L) and objv (n_sub, n_ind), "
                         f"got {c.shape} and {o.shape}")
    n_sub, n_ind = o.shape
    k = n_migrants(n_ind, rate)
    if n_sub < 2 or k == 0:
        return c, o
    order = np.argsort(_worst_key(o), axis=1, kind="stable")
    emi = order[:, :k]  # (n_sub, k) best of each
    emi_chrom = np.take_along_axis(c, emi[:, :, None], axis=1)  # (n_sub, k, L)
    emi_objv = np.take_along_axis(o, emi, axis=1)  # (n_sub, k)
    worst = order[:, n_ind - k:]
    for i in range(n_sub):
        if topology == "complete":
            src = [j for j in range(n_sub) if j != i]
        elif topology == "neighbourhood":
            src = sorted({(i - 1) % n_sub, (i + 1) % n_sub})
        else:
            src = [(i - 1) % n_sub]
        pool_c = emi_chrom[src].reshape(-1, c.shape[2])
        pool_o = emi_objv[src].reshape(-1)
        if immigrants == "uniform":
            pick = rng.choice(pool_o.size, size=k, replace=False)
        else:
            pick = np.argsort(_worst_key(pool_o), kind="stable")[:k]
        c[i, worst[i]] = pool_c[pick]
        o[i, worst[i]] = pool_o[pick]
    return c, o


# --------------------------------------------------------------------------
# Driver
# --------------------------------------------------------------------------
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
        ``'mean'``: mean of the finite objectives in the population;
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
    return _worst_key(y.reshape(X.shape[0]))


def _cap(objv: np.ndarray, early_stop: Optional[float]) -> Optional[float]:
    """Early-termination cap: a quantile of the population's finite objectives."""
    if early_stop is None:
        return None
    finite = objv[np.isfinite(objv)]
    return float(np.quantile(finite, float(early_stop))) if finite.size else None


def _finite_mean(o: np.ndarray) -> float:
    f = o[np.isfinite(o)]
    return float(f.mean()) if f.size else float("nan")


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
    callback : callable, optional
        ``callback(GAState) -> bool`` after every generation; True stops.
    progress : bool
        Show a tqdm bar per generation with the best objective (only when
        stderr is a terminal).
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

    Returns
    -------
    GAResult
        A KeyboardInterrupt raised in ``evaluate`` or the loop, or a
        callback returning True, ends the search early: the best so far is
        returned with ``interrupted=True``.  (An interrupt while the
        initial population is evaluated propagates: there is no "so far".)
    """
    from tqdm.auto import tqdm

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
    if topology not in _TOPOLOGIES or immigrants not in ("uniform", "best"):
        raise ValueError(f"bad topology {topology!r} or immigrants {immigrants!r}")
    migration_interval = int(migration_interval)
    if early_stop is not None and not (0.0 <= float(early_stop) <= 1.0):
        raise ValueError(f"early_stop must be a quantile in [0, 1] or None, got {early_stop}")

    rng = _rng(rng)
    enc = BinaryEncoding(bounds, bits=bits, gray=gray)
    L, n = enc.length, enc.n_genes
    n_total = n_subpops * n_ind
    n_sel = n_offspring(n_ind, ggap)

    chrom = enc.random(n_total, rng)
    if initial is not None:
        x0 = np.atleast_2d(np.asarray(initial, dtype=float))
        if x0.ndim != 2 or x0.shape[1] != n:
            raise ValueError(f"initial points must have shape (k, {n}), got {np.shape(initial)}")
        if x0.shape[0] > n_total:
            raise ValueError(f"{x0.shape[0]} initial points exceed the population of {n_total}")
        i = np.arange(x0.shape[0])
        chrom[(i % n_subpops) * n_ind + i // n_subpops] = enc.encode(x0)
    chrom = chrom.reshape(n_subpops, n_ind, L)

    objv = _evaluate(evaluate, enc.decode(chrom.reshape(-1, L))).reshape(n_subpops, n_ind)
    ib = int(np.argmin(objv))
    # State is kept in tuples replaced by single assignments / appends, so that
    # a KeyboardInterrupt arriving anywhere leaves a consistent "best so far".
    pop = (chrom, objv)
    best = (float(objv.reshape(-1)[ib]), enc.decode(chrom.reshape(-1, L)[ib]), n_total)
    hist = [(float(objv.min()), best[0], _finite_mean(objv), n_total)]

    interrupted = False
    message = f"completed {n_gen} generations"
    # disable=None: tqdm switches itself off when stderr is not a terminal (no
    # carriage-return flood in a log file)
    bar = tqdm(total=n_gen, desc="GA", unit="gen", disable=None if progress else True,
               leave=False)
    try:
        bar.set_postfix(best=f"{best[0]:.6g}")
        for gen in range(1, n_gen + 1):
            try:
                chrom, objv = pop
                off = np.empty((n_subpops, n_sel, L), dtype=chrom.dtype)
                for s in range(n_subpops):
                    sel = chrom[s, sus(ranking(objv[s], sp), n_sel, rng)]
                    sel = crossover_single_point(sel, p_xover, rng)
                    off[s] = mutate(sel, p_mut, rng)
                X_off = enc.decode(off.reshape(-1, L))
                objv_off = _evaluate(evaluate, X_off, _cap(objv, early_stop))
                j = int(np.argmin(objv_off))
                n_eval = best[2] + X_off.shape[0]
                if objv_off[j] < best[0]:
                    best = (float(objv_off[j]), X_off[j].copy(), n_eval)
                else:
                    best = (best[0], best[1], n_eval)
                objv_off = objv_off.reshape(n_subpops, n_sel)
                new_chrom = np.empty_like(chrom)
                new_objv = np.empty_like(objv)
                for s in range(n_subpops):
                    new_chrom[s], new_objv[s] = reinsert(chrom[s], objv[s], off[s], objv_off[s])
                if (migration_interval and n_subpops > 1 and gen % migration_interval == 0
                        and gen < n_gen):
                    new_chrom, new_objv = migrate(new_chrom, new_objv, migration_rate, rng,
                                                  topology=topology, immigrants=immigrants)
                pop = (new_chrom, new_objv)
                hist.append((float(new_objv.min()), best[0], _finite_mean(new_objv), n_eval))
                bar.update(1)
                bar.set_postfix(best=f"{best[0]:.6g}")
                if callback is not None and callback(GAState(
                        generation=gen, x=best[1].copy(), fun=best[0], mean=hist[-1][2],
                        nfev=n_eval)):
                    interrupted = True
                    message = f"stopped by callback after generation {gen}"
                    break
            except KeyboardInterrupt:
                interrupted = True
                message = f"interrupted (KeyboardInterrupt) after generation {len(hist) - 1}"
                break
    finally:
        bar.close()

    chrom, objv = pop
    h = np.asarray(hist, dtype=float).reshape(-1, 4)
    return GAResult(
        x=np.asarray(best[1], dtype=float),
        fun=best[0],
        nfev=int(best[2]),
        nit=len(hist) - 1,
        success=not interrupted,
        message=message,
        population=enc.decode(chrom.reshape(-1, L)),
        population_energies=objv.reshape(-1).copy(),
        history={
            "best": h[:, 0].copy(),
            "best_so_far": h[:, 1].copy(),
            "mean": h[:, 2].copy(),
            "nfev": h[:, 3].astype(np.int64),
        },
        interrupted=interrupted,
    )
