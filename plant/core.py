"""The one closed-loop core: one sample step that every simulation drives.

Every simulation in the library -- the logged P-control experiment
(:mod:`plant.simulate`), the logged-input replay of the refinement
(:mod:`plant.replay`), the loop with any sampled controller
(:mod:`plant.closed_loop`), rigid or two-mass flexible plant, one candidate
or a batch of candidates in SIMD lanes -- advances the robot through the
functions of this module and nothing else::

        encoder_read          the rig's card at t_k: counts trunc(q k N / 2 pi)
             |
        (driver: the control law, e.g. i = P e, or a Python controller)
             |
        advance_sample        the current i held over [t_k, t_k + Ts):
             |                RK4 substeps of the plant's right-hand side
             v
        next sample

* :func:`encoder_read` reads an angle as the card does (continuous count and
  its truncation toward zero); :func:`cell_centre` gives the centre of the
  continuous counts an integer count allows.
* :func:`advance_sample` advances lanes ``0..n-1`` of a state array ``X``
  (rows: state components, columns: lanes) over one sample with the held
  motor currents ``U`` (2, lanes), by ``substeps`` classical RK4 steps of the
  plant's right-hand side.  The plant is a *parameter* (its ``kind``, a
  type tag whose numba type is known at compile time): :func:`plant_rhs` is
  the one place where a kind becomes its right-hand side (the registry
  :data:`plant.plants.RIGHT_HAND_SIDES`: rigid or flexible), so every kernel
  is compiled once per plant with only that plant's right-hand side, and is
  not a copy of the loop.  (A kind rather than a compiled function passed as
  an argument: numba cannot load kernels that take functions as arguments
  from its on-disk cache in a new process, so they would compile at every
  run.)

A plant's right-hand side has the signature ``rhs(P, c, X, U, A, K, n)``:
per-lane parameters ``P`` (n_par, lanes), the rig layout ``c``
(:class:`plant.rig.RigConstants`), the stage state ``X`` (n_x, lanes), the
held currents ``U`` (2, lanes), the trigonometric anchors ``A`` (6, lanes;
:mod:`plant.anchors`) and the output ``K`` (n_x + 1, lanes): rows
``0..n_x-1`` the state derivative, row ``n_x`` a positive-definiteness
margin (det D(q); a stage with a margin <= 0 is rejected).  Rows 0 and 1 of
every plant's state are the link angles q2, q3 (the only angles whose sine
and cosine the dynamics need).

Lanes
-----
One RK4 stage is a dependent chain (trigonometry -> D, h, g -> 2x2 solve ->
next stage), so a single candidate leaves the CPU waiting on latencies.
The core keeps one column per candidate and runs every step as a loop over
the lanes with no calls that stay calls and no data-dependent control flow,
so that LLVM turns them into SIMD instructions over several candidates at
once.  A loop writes one array and reads others, which keeps LLVM's run-time
overlap checks few enough for it to vectorise.  Per lane the floating-point
operations are the same whatever the number of lanes, so a lane's result
does not depend on its neighbours (tested): one candidate is one lane.

The sample step and the right-hand side are inlined in numba's IR into the
driver that calls them (``inline="always"``), and :func:`advance_sample`
calls the right-hand side at one place, in a loop over the four RK4 stages:
a compiled call that passes arrays costs atomic reference-count updates per
array, which per stage and sample took more time than the arithmetic of 40
lanes (measured: the paper's GA budget 0.83 s with calls, 0.69 s inlined),
and one inlined copy keeps the compile time down.

Trigonometry
------------
The stages take sin/cos of the link angles by angle addition from the
sample's start angles (:mod:`plant.anchors`); a lane that moved further than
:data:`~plant.anchors.SINCOS_RANGE` within a sample is recomputed with libm.

Status codes
------------
:data:`STATUS_OK`, :data:`STATUS_NOT_PD` (D(q) not positive definite at some
stage; the lane keeps the state of the step's start), :data:`STATUS_NONFINITE`,
and the drivers' :data:`STATUS_DIVERGED`, :data:`STATUS_STOPPED`; messages in
:data:`STATUS_MESSAGES`.
"""
from __future__ import annotations

import math

import numba
import numpy as np

from numba import types
from numba.core.errors import TypingError
from numba.extending import overload

from .anchors import update_anchors
from .plants import RIGHT_HAND_SIDES

__all__ = [
    "STATUS_OK",
    "STATUS_NOT_PD",
    "STATUS_NONFINITE",
    "STATUS_DIVERGED",
    "STATUS_STOPPED",
    "STATUS_MESSAGES",
    "encoder_read",
    "cell_centre",
    "plant_rhs",
    "advance_sample",
    "new_workspace",
    "padded_lanes",
]

STATUS_OK = 0
STATUS_NOT_PD = 1
STATUS_NONFINITE = 2
STATUS_DIVERGED = 3
STATUS_STOPPED = 4
#: Human-readable reason of each status code.
STATUS_MESSAGES = {
    STATUS_OK: "ok",
    STATUS_NOT_PD: "D(q) not positive definite",
    STATUS_NONFINITE: "state not finite",
    STATUS_DIVERGED: "simulated tracking error left the bound",
    STATUS_STOPPED: "output error passed the early-termination cap",
}

#: Lane loops run over a multiple of this many lanes from this many on (AVX2:
#: 4 doubles per vector, twice that for AVX-512), so that no lane falls into
#: a scalar remainder loop; the extra columns are padding copies.
LANE_PAD = 8

# Helpers compiled into the kernels that call them (whose cache holds their code):
# not cached on their own, which saves a cache file and its write per helper.
_jit = numba.njit(nogil=True, error_model="numpy")


@_jit
def encoder_read(angle, pulses_per_rad):
    """Read one motor encoder as the rig's card does.

    Parameters
    ----------
    angle : float
        Joint-side angle the encoder sees (rad): the joint angle of a rigid
        robot, the motor angle divided by k of a flexible one.
    pulses_per_rad : float
        k N / (2 pi) (pulses per joint radian).

    Returns
    -------
    continuous : float
        ``angle k N / 2 pi`` (pulses).
    count : float
        ``trunc(continuous)`` (an integer; trunc rounds toward zero).
    """
    c = angle * pulses_per_rad
    return c, float(math.trunc(c))


@_jit
def cell_centre(count):
    """Centre of the continuous counts c with ``trunc(c) == count`` (pulses).

    The cell of a count a > 0 is [a, a + 1), of a < 0 (a - 1, a], of 0 the
    interval (-1, 1): centres a + 0.5, a - 0.5 and 0.

    Parameters
    ----------
    count : float
        An integer count.

    Returns
    -------
    float
    """
    if count > 0.0:
        return count + 0.5
    if count < 0.0:
        return count - 0.5
    return 0.0


@_jit
def padded_lanes(n):
    """Lanes a SIMD loop runs over for ``n`` active lanes.

    A multiple of :data:`LANE_PAD` from ``LANE_PAD`` lanes on; fewer lanes
    are not padded (they run in the loops' scalar remainder instead of paying
    for a whole vector of copies).

    Parameters
    ----------
    n : int
        Active lanes.

    Returns
    -------
    int
    """
    if n < LANE_PAD:
        return n
    return (n + LANE_PAD - 1) // LANE_PAD * LANE_PAD


def new_workspace(nx, lanes):
    """Scratch arrays of :func:`advance_sample` for ``nx`` states and ``lanes`` lanes.

    Parameters
    ----------
    nx : int
        State components.
    lanes : int
        Lanes (columns).

    Returns
    -------
    tuple of ndarray
        ``(K1, K2, K3, K4, XS)``: the four stage derivatives (nx + 1, lanes)
        and the stage state (nx, lanes).
    """
    return tuple(np.zeros((nx + 1, lanes)) for _ in range(4)) + (np.zeros((nx, lanes)),)


@numba.njit(nogil=True, error_model="numpy", inline="always")  # IR-inlined: no call in the sample loop
def _stage_state(X, K, c, XS, nx, n):
    """Next stage's state ``XS = X + c K`` (rows 0..nx-1)."""
    for i in range(nx):
        for j in range(n):
            XS[i, j] = X[i, j] + c * K[i, j]


def plant_rhs(kind, P, c, X, U, A, K, n):
    """The right-hand side of plant ``kind``: the one place a kind becomes its function.

    Compiled code only: the *type* of ``kind`` selects the function at
    compile time (:data:`plant.plants.RIGHT_HAND_SIDES` maps kind classes to
    functions), so that a kernel compiles the right-hand side of its own
    plant and no other.

    Parameters
    ----------
    kind : plant.plants.RigidKind or plant.plants.FlexibleKind
        A plant's :attr:`~plant.plants.Plant.kind`.
    P, c, X, U, A, K, n
        As the right-hand sides of :mod:`plant.plants`.

    Raises
    ------
    numba.core.errors.TypingError
        At compile time, for a kind that is not registered.
    """
    raise NotImplementedError("plant_rhs is called from compiled code only")


@overload(plant_rhs, jit_options=dict(nogil=True, error_model="numpy"), inline="always")
def _plant_rhs_overload(kind, P, c, X, U, A, K, n):
    rhs = RIGHT_HAND_SIDES.get(getattr(kind, "instance_class", None))
    if not isinstance(kind, types.BaseNamedTuple) or rhs is None:
        raise TypingError(f"unknown plant kind {kind}; register it in plant.plants.RIGHT_HAND_SIDES")

    def impl(kind, P, c, X, U, A, K, n):
        rhs(P, c, X, U, A, K, n)

    return impl


@numba.njit(nogil=True, error_model="numpy", inline="always")  # IR-inlined (plant.core)
def advance_sample(kind, P, c, X, U, A, S, W, n, substeps, reanchor):
    """Advance lanes ``0..n-1`` over one sample with the held currents ``U``.

    Classical 4th-order Runge-Kutta with ``substeps`` equal steps over
    ``Ts = c.sample_time_s`` of the plant's right-hand side ``rhs`` (see the
    module docstring for its signature); the currents are held constant over
    the sample (zero-order hold, as the rig's amplifiers do).

    Parameters
    ----------
    kind : plant.plants.RigidKind or plant.plants.FlexibleKind
        The plant (:attr:`plant.plants.Plant.kind`); its right-hand side is
        chosen by :func:`plant_rhs`.
    P : ndarray, shape (n_par, lanes)
        Per-lane plant parameters (column j: lane j).
    c : plant.rig.RigConstants
        Rig layout.
    X : ndarray, shape (n_x, lanes)
        State at the sample's start; advanced in place.
    U : ndarray, shape (2, lanes)
        Motor currents (A) held over the sample.
    A : ndarray, shape (6, lanes)
        Trigonometric anchors (see the module docstring); updated in place.
    S : ndarray, shape (lanes,), int64
        Status per lane: set to :data:`STATUS_NOT_PD` or
        :data:`STATUS_NONFINITE` on failure (a lane already failed keeps its
        code).
    W : tuple of ndarray
        Scratch from :func:`new_workspace`.
    n : int
        Number of lanes to advance (columns ``0..n-1``).
    substeps : int
        RK4 steps per sample (>= 1).
    reanchor : bool
        Take the anchors' sin/cos from libm at this sample.
    """
    K1, K2, K3, K4, XS = W
    nx = X.shape[0]
    h = c.sample_time_s / substeps
    hh = 0.5 * h
    h6 = h * (1.0 / 6.0)
    update_anchors(X, A, n, reanchor)
    stages = (K1, K2, K3, K4)
    steps = (hh, hh, h, h)
    for _ in range(substeps):
        for s in range(4):
            # one (inlined) right-hand side for the four stages: a call per
            # stage would cost atomic reference-count updates of its arrays
            K = stages[s]
            plant_rhs(kind, P, c, X if s == 0 else XS, U, A, K, n)
            if s < 3:
                _stage_state(X, K, steps[s], XS, nx, n)
        for i in range(nx):
            for j in range(n):
                ok = K1[nx, j] > 0.0 and K2[nx, j] > 0.0 and K3[nx, j] > 0.0 and K4[nx, j] > 0.0
                x = X[i, j]
                X[i, j] = (x + h6 * (K1[i, j] + 2.0 * K2[i, j] + 2.0 * K3[i, j] + K4[i, j])
                           if ok else x)
        for j in range(n):
            if not (K1[nx, j] > 0.0 and K2[nx, j] > 0.0 and K3[nx, j] > 0.0
                    and K4[nx, j] > 0.0) and S[j] == STATUS_OK:
                S[j] = STATUS_NOT_PD
    for j in range(n):
        if S[j] == STATUS_OK:
            for i in range(nx):
                if not math.isfinite(X[i, j]):
                    S[j] = STATUS_NONFINITE
                    break
