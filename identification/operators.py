"""Operators of the paper's multi-population binary GA (pure functions).

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
from typing import Optional, Sequence, Union

import numpy as np

__all__ = [
    "RngLike",
    "BinaryEncoding",
    "ranking",
    "sus",
    "crossover_single_point",
    "mutate",
    "reinsert",
    "migrate",
    "n_offspring",
    "n_migrants",
    "worst_key",
    "TOPOLOGIES",
]

RngLike = Union[np.random.Generator, int, None]


def as_rng(rng: RngLike) -> np.random.Generator:
    """``rng`` as a :class:`numpy.random.Generator` (an int or None seeds a new one)."""
    return rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)


def _round_half_up(x: float) -> int:
    """Round like MATLAB's ``floor(x + .5)`` (Python's round() is banker's)."""
    return int(math.floor(x + 0.5))


def worst_key(objv) -> np.ndarray:
    """Objective values as float with every non-finite value mapped to +inf.

    Parameters
    ----------
    objv : array_like
        Objective values.

    Returns
    -------
    ndarray
    """
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

        Parameters
        ----------
        m : int
            Number of chromosomes.
        rng : numpy.random.Generator, int or None
            Random source.

        Returns
        -------
        ndarray of uint8, shape (m, L)
        """
        return as_rng(rng).integers(0, 2, size=(int(m), self.length), dtype=np.uint8)


# --------------------------------------------------------------------------
# Operators
# --------------------------------------------------------------------------
def _average_ranks(a) -> np.ndarray:
    """Ranks 1..N along the last axis, ties sharing their average rank.

    The same as ``scipy.stats.rankdata(a, method='average', axis=-1)``
    (tested), without importing scipy.stats (half a second at start-up).
    """
    a = np.asarray(a, dtype=float)
    flat = a.reshape(-1, a.shape[-1])
    out = np.empty_like(flat)
    n = flat.shape[1]
    for r, row in enumerate(flat):
        order = np.argsort(row, kind="stable")
        srt = row[order]
        # start of each run of equal values, and its average rank
        new = np.r_[True, srt[1:] != srt[:-1]]
        starts = np.flatnonzero(new)
        ends = np.r_[starts[1:], n]
        avg = 0.5 * (starts + ends - 1) + 1.0
        out[r, order] = np.repeat(avg, ends - starts)
    return out.reshape(a.shape)


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
    key = worst_key(objv)
    n = key.shape[-1] if key.ndim else 1
    if key.ndim == 0 or n == 1:
        return np.ones_like(key, dtype=float)
    # rank 1 = largest objective (worst); inf ties share the lowest ranks
    pos = _average_ranks(-key)
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
    rng = as_rng(rng)
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
    rng = as_rng(rng)
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
    flip = as_rng(rng).random(c.shape) < p
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
        keep = np.argsort(worst_key(off_objv), kind="stable")[:n_ins]
        off, off_objv = off[keep], off_objv[keep]
    worst = np.argsort(worst_key(objv), kind="stable")[chrom.shape[0] - n_ins:]
    chrom[worst] = off
    objv[worst] = off_objv
    return chrom, objv


def n_offspring(n_ind: int, ggap: float) -> int:
    """Offspring per subpopulation: ``max(floor(ggap * n_ind + 0.5), 2)``, at most ``n_ind``.

    As the toolbox's ``select``: 19 for 20 individuals at ggap 0.94.

    Parameters
    ----------
    n_ind : int
        Individuals per subpopulation.
    ggap : float
        Generation gap in (0, 1].

    Returns
    -------
    int
    """
    return min(max(_round_half_up(ggap * n_ind), 2), int(n_ind))


def n_migrants(n_ind: int, rate: float) -> int:
    """Migrants per subpopulation: ``floor(rate * n_ind + 0.5)``, capped at ``n_ind - 1``.

    6 for 20 individuals at rate 0.3.  The cap keeps every subpopulation's
    best individual at home.

    Parameters
    ----------
    n_ind : int
        Individuals per subpopulation.
    rate : float
        Migration rate in [0, 1].

    Returns
    -------
    int
    """
    return max(0, min(_round_half_up(rate * n_ind), int(n_ind) - 1))


TOPOLOGIES = ("complete", "neighbourhood", "ring")


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
    if topology not in TOPOLOGIES:
        raise ValueError(f"topology must be one of {TOPOLOGIES}, got {topology!r}")
    if immigrants not in ("uniform", "best"):
        raise ValueError(f"immigrants must be 'uniform' or 'best', got {immigrants!r}")
    if not (0.0 <= rate <= 1.0):
        raise ValueError(f"migration rate must be in [0, 1], got {rate}")
    rng = as_rng(rng)
    c = np.array(chroms, copy=True)
    o = np.array(objv, dtype=float, copy=True)
    if c.ndim != 3 or o.shape != c.shape[:2]:
        raise ValueError(f"need chroms (n_sub, n_ind, L) and objv (n_sub, n_ind), "
                         f"got {c.shape} and {o.shape}")
    n_sub, n_ind = o.shape
    k = n_migrants(n_ind, rate)
    if n_sub < 2 or k == 0:
        return c, o
    order = np.argsort(worst_key(o), axis=1, kind="stable")
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
            pick = np.argsort(worst_key(pool_o), kind="stable")[:k]
        c[i, worst[i]] = pool_c[pick]
        o[i, worst[i]] = pool_o[pick]
    return c, o
