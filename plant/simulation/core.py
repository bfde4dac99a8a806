"""The one closed-loop core: one sample step that every simulation drives.

Every simulation in the library -- the logged P-control experiment
(:mod:`plant.simulation.simulate`), the logged-input replay of the refinement
(:mod:`plant.simulation.replay`), the loop with any sampled controller
(:mod:`plant.simulation.closed_loop`), rigid or two-mass flexible plant, one candidate
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

* :func:`hold_and_advance` is the closed loop's sample step of one lane:
  the controller's currents held, then :func:`advance_sample` (compiled by
  :mod:`plant.simulation.closed_loop` for the PUMA 560 plants; each robot
  model's generated module compiles a copy for its kind).
* :func:`encoder_read` reads an angle as the card does (continuous count and
  its truncation toward zero); :func:`cell_centre` gives the centre of the
  continuous counts an integer count allows.
* :func:`advance_sample` advances lanes ``0..n-1`` of a state array ``X``
  (rows: state components, columns: lanes) over one sample with the held
  motor currents ``U`` (2, lanes), by ``substeps`` classical RK4 steps of the
  plant's right-hand side.  The plant is a *parameter* (its ``kind``, a
  type tag whose numba type is known at compile time): :func:`plant_rhs` is
  the one place where a kind becomes its right-hand side (the registry
  :data:`plant.simulation.plants.RIGHT_HAND_SIDES`: rigid or flexible), so every kernel
  is compiled once per plant with only that plant's right-hand side, and is
  not a copy of the loop.  (A kind rather than a compiled function passed as
  an argument: numba cannot load kernels that take functions as arguments
  from its on-disk cache in a new process, so they would compile at every
  run.)

A plant's right-hand side is a function of one lane with the signature
``rhs(p, c, x, u, sc) -> (xdot, margin)``: the lane's parameters ``p`` (a
tuple of n_par floats, :func:`lane_parameters`), the rig layout ``c`` (a
``NamedTuple`` with at least ``sample_time_s``, e.g.
:class:`plant.logs.rig.RigConstants`), the stage state ``x`` (a tuple of n_x
floats), the held motor currents ``u`` (a tuple of n_u floats, A; one per
driven joint) and ``sc = (sin x[0], cos x[0], ..., sin x[m-1], cos x[m-1])``
for the plant's first m states, its angles whose sine and cosine the
dynamics need; it returns the state derivative (a tuple of n_x floats) and a
positive-definiteness margin (e.g. det D(q) or the smallest Cholesky pivot;
a stage with a margin <= 0 is rejected).  The sizes n_x, n_par, n_u and m
are the plant's registration (:func:`plant.simulation.plants.register_plant`): the
PUMA 560 links 2-3 have n_u = m = 2 (q2, q3), a robot model's rigid arm
(:mod:`plant.simulation.arm`) one of each per joint.  No arrays cross the right-hand
side, so nothing is reference-counted inside the loops.

Lanes
-----
One RK4 stage is a dependent chain (trigonometry -> D, h, g -> 2x2 solve ->
next stage), so a single candidate leaves the CPU waiting on latencies.
The core keeps one column per candidate and advances all of them with *one
loop over the lanes per RK4 step* (:func:`rk4_lane`): the lane's state, its
parameters and its four stages stay in registers, the loop body has no
calls that stay calls and no data-dependent control flow, so LLVM turns it
into SIMD instructions over 8 candidates at once (AVX-512).  Per lane the
floating-point operations are the same whatever the number of lanes, so a
lane's result does not depend on its neighbours (tested): one candidate is
one lane.  (An earlier layout ran a loop over the lanes per stage and per
state row, about 30 loops a sample, writing the stages to arrays; one loop
per step removed most of the fixed cost per sample and part of the cost per
lane: ``benchmarks/bench_versus.py``, ``docs/speed.rst``.)

:func:`rk4_lane` and :func:`advance_sample` are inlined in numba's IR into
the driver that calls them (``inline="always"``) so that the switch
``exact`` folds away in the SIMD loop.  So are :func:`plant_rhs` and, with
``exact`` known False, :func:`~plant.simulation.anchors.lane_sincos` (its
branch-free variant): a call that stays a call stops vectorisation, and
LLVM's inliner declines functions of a few hundred operations called at
four stages.  A right-hand side is a compiled function that LLVM inlines
when it is small (the PUMA 560 links 2-3), or, generated for a robot model,
one that numba inlines up to a size
(:data:`plant.simulation.arm.INLINE_MAX_INSTRUCTIONS`).  Nothing inlined in
numba's IR takes an array (that leaves reference-count updates in the
loop) or branches (numba's inliner then warns).  With three joints or more
the lane loop reads and writes more state rows than LLVM checks for
aliasing by default; :data:`RUNTIME_MEMORY_CHECKS` raises that limit.

Trigonometry
------------
The stages take sin/cos of the link angles by angle addition from the
sample's start angles (:mod:`plant.simulation.anchors`); a lane that moved further than
:data:`~plant.simulation.anchors.SINCOS_RANGE` within a sample is recomputed with libm.

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

from plant.simulation.anchors import REANCHOR, lane_sincos, update_anchors, update_anchors_impl
from plant.simulation.plants import RIGHT_HAND_SIDES

#: LLVM's limit on the run-time alias checks of a loop it vectorises
#: (``-vectorize-memory-check-threshold``, default 128), set for the process when
#: this module is imported.  The lane loop of an n-joint arm stores 2 n state rows
#: (4 n flexible) of one array and reads them, its parameters, inputs and anchors
#: from others; beyond two joints that needs more checks than the default and LLVM
#: left the loop scalar (PUMA 560 joints 1-3, rigid: 155 against 22-27 ns per lane
#: and RK4 step, ``benchmarks/bench_arm_kernels.py``).  The checks run once per
#: loop, not per lane, and change no result (a lane's operations are the same in
#: SIMD or not).
RUNTIME_MEMORY_CHECKS = 4096


def _allow_memory_checks():
    try:
        import llvmlite.binding as llvm

        llvm.set_option("", f"-vectorize-memory-check-threshold={RUNTIME_MEMORY_CHECKS}")
    except Exception:  # noqa: BLE001 - an LLVM without the option: slower, not wrong
        pass


_allow_memory_checks()

__all__ = [
    "STATUS_OK",
    "STATUS_NOT_PD",
    "STATUS_NONFINITE",
    "STATUS_DIVERGED",
    "STATUS_STOPPED",
    "STATUS_MESSAGES",
    "encoder_read",
    "cell_centre",
    "cell_centres",
    "plant_rhs",
    "rk4_lane",
    "lane_state",
    "lane_parameters",
    "lane_inputs",
    "lane_anchors",
    "anchors_update",
    "store_lane_state",
    "advance_sample",
    "hold_and_advance",
    "new_workspace",
    "padded_lanes",
    "RUNTIME_MEMORY_CHECKS",
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

#: Lane loops run over a multiple of this many lanes from two lanes on (AVX2:
#: 4 doubles per vector, twice that for AVX-512), so that no lane falls into
#: a scalar remainder loop; the extra columns are padding copies
#: (:func:`padded_lanes`).
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


def cell_centres(counts):
    """:func:`cell_centre` on an array of integer counts (plain numpy: calling the compiled
    helper from Python would compile it at its first call, ~0.3 s).

    Parameters
    ----------
    counts : array_like
        Integer counts (any shape).

    Returns
    -------
    ndarray
        The centres (pulses), the shape of ``counts``.
    """
    a = np.asarray(counts, dtype=float)
    return np.where(a > 0.0, a + 0.5, np.where(a < 0.0, a - 0.5, 0.0))


@_jit
def padded_lanes(n):
    """Lanes a SIMD loop runs over for ``n`` active lanes.

    A multiple of :data:`LANE_PAD` from two lanes on (a whole vector with
    copies in the spare lanes costs less than two or more lanes in the loop's
    scalar remainder: ``benchmarks/bench_simulate.py``); one lane is not
    padded.

    Parameters
    ----------
    n : int
        Active lanes.

    Returns
    -------
    int
    """
    if n < 2:
        return n
    return (n + LANE_PAD - 1) // LANE_PAD * LANE_PAD


def new_workspace(nx, lanes):
    """Scratch of :func:`advance_sample` for ``lanes`` lanes.

    Parameters
    ----------
    nx : int
        State components (unused: the per-lane state lives in registers).
    lanes : int
        Lanes (columns).

    Returns
    -------
    ndarray, shape (lanes,), int64
        Per-lane outcome of a step inside :func:`advance_sample` (done, D(q)
        not positive definite, or too far from the anchors).
    """
    return np.zeros(lanes, dtype=np.int64)


# Outcomes of one lane's step in the SIMD loop of advance_sample (its scratch W).
_LANE_DONE, _LANE_NOT_PD, _LANE_FAR = 0, 1, 2


# ----------------------------------------------------------------------------
# Per-lane tuples: code generated once per state size
# ----------------------------------------------------------------------------
def _generated(name, params, lines):
    """A Python function ``name(params)`` with the body ``lines`` (overload impls)."""
    src = f"def {name}({params}):\n" + "".join(f"    {line}\n" for line in lines)
    scope = {"math": math}
    exec(compile(src, f"<plant.simulation.core.{name}>", "exec"), scope)  # noqa: S102 - fixed templates
    return scope[name]


def _registered(kind):
    """The :class:`plant.simulation.plants.RightHandSide` of a plant kind's numba type (typing time)."""
    entry = RIGHT_HAND_SIDES.get(getattr(kind, "instance_class", None))
    if not isinstance(kind, types.BaseNamedTuple) or entry is None:
        raise TypingError(f"unknown plant kind {kind}; register it with plant.simulation.plants.register_plant")
    return entry


def lane_state(kind, X, j):
    """Lane ``j``'s state as a tuple ``(X[0, j], ..., X[n_x - 1, j])``.

    Parameters
    ----------
    kind : NamedTuple
        A plant kind (its registered state size gives ``n_x``).
    X : ndarray, shape (n_x, lanes)
        States.
    j : int
        Lane.

    Returns
    -------
    tuple of n_x float
    """
    return tuple(float(v) for v in X[:RIGHT_HAND_SIDES[type(kind)].n_states, j])


@overload(lane_state, jit_options=dict(nogil=True, error_model="numpy"), inline="always")
def _lane_state_overload(kind, X, j):
    return _tuple_impl("kind, X, j", _registered(kind).n_states, lambda i: f"X[{i}, j]")


def lane_parameters(kind, P, j):
    """Lane ``j``'s plant parameters as a tuple ``(P[0, j], ..., P[n_par - 1, j])``.

    Parameters
    ----------
    kind : NamedTuple
        A plant kind (its registered parameter count gives ``n_par``).
    P : ndarray, shape (n_par, lanes)
        Per-lane parameters.
    j : int
        Lane.

    Returns
    -------
    tuple of n_par float
    """
    return tuple(float(v) for v in P[:RIGHT_HAND_SIDES[type(kind)].n_parameters, j])


@overload(lane_parameters, jit_options=dict(nogil=True, error_model="numpy"), inline="always")
def _lane_parameters_overload(kind, P, j):
    return _tuple_impl("kind, P, j", _registered(kind).n_parameters, lambda i: f"P[{i}, j]")


def lane_inputs(kind, U, j):
    """Lane ``j``'s held motor currents as a tuple ``(U[0, j], ..., U[n_u - 1, j])``.

    Parameters
    ----------
    kind : NamedTuple
        A plant kind (its registered input count gives ``n_u``).
    U : ndarray, shape (n_u, lanes)
        Motor currents (A).
    j : int
        Lane.

    Returns
    -------
    tuple of n_u float
    """
    return tuple(float(v) for v in U[:RIGHT_HAND_SIDES[type(kind)].n_inputs, j])


@overload(lane_inputs, jit_options=dict(nogil=True, error_model="numpy"), inline="always")
def _lane_inputs_overload(kind, U, j):
    return _tuple_impl("kind, U, j", _registered(kind).n_inputs, lambda i: f"U[{i}, j]")


def lane_anchors(kind, A, j):
    """Lane ``j``'s trigonometric anchors as a tuple of ``3 m`` floats (:mod:`plant.simulation.anchors`).

    Parameters
    ----------
    kind : NamedTuple
        A plant kind (its registered angle count gives ``m``).
    A : ndarray, shape (3 m, lanes)
        Anchors.
    j : int
        Lane.

    Returns
    -------
    tuple of 3 m float
    """
    return tuple(float(v) for v in A[:3 * RIGHT_HAND_SIDES[type(kind)].n_angles, j])


@overload(lane_anchors, jit_options=dict(nogil=True, error_model="numpy"), inline="always")
def _lane_anchors_overload(kind, A, j):
    return _tuple_impl("kind, A, j", 3 * _registered(kind).n_angles, lambda i: f"A[{i}, j]")


def anchors_update(kind, X, A, n, reanchor):
    """:func:`plant.simulation.anchors.update_anchors` for plant ``kind`` (compiled per its angle count).

    Parameters
    ----------
    kind : NamedTuple
        A plant kind (its registered ``n_angles`` gives m).
    X, A, n, reanchor
        As :func:`plant.simulation.anchors.update_anchors`.
    """
    update_anchors(X, A, n, reanchor)


@overload(anchors_update, jit_options=dict(nogil=True, error_model="numpy"), inline="always")
def _anchors_update_overload(kind, X, A, n, reanchor):
    return update_anchors_impl(_registered(kind).n_angles)


def store_lane_state(X, j, x):
    """``X[:, j] = x`` for a state tuple ``x``.

    Parameters
    ----------
    X : ndarray, shape (n_x, lanes)
    j : int
    x : tuple of n_x float
    """
    X[:len(x), j] = x


@overload(store_lane_state, jit_options=dict(nogil=True, error_model="numpy"), inline="always")
def _store_lane_state_overload(X, j, x):
    return _generated("impl", "X, j, x", [f"X[{i}, j] = x[{i}]" for i in range(len(x))]
                      + ["return None"])


def _tuple_impl(params, n, element):
    """Implementation returning the tuple ``(element(0), ..., element(n - 1))``."""
    return _generated("impl", params,
                      ["return (" + "".join(element(i) + ", " for i in range(n)) + ")"])


def _axpy(x, a, k):
    """``x + a k`` elementwise for tuples (RK4 stage state)."""
    return tuple(xi + a * ki for xi, ki in zip(x, k))


@overload(_axpy, jit_options=dict(nogil=True, error_model="numpy"))
def _axpy_overload(x, a, k):
    return _tuple_impl("x, a, k", len(x), lambda i: f"x[{i}] + a * k[{i}]")


def _rk4_sum(x, h6, k1, k2, k3, k4):
    """``x + h6 (k1 + 2 k2 + 2 k3 + k4)`` elementwise (RK4 step)."""
    return tuple(xi + h6 * (a + 2.0 * b + 2.0 * c + d) for xi, a, b, c, d in zip(x, k1, k2, k3, k4))


@overload(_rk4_sum, jit_options=dict(nogil=True, error_model="numpy"))
def _rk4_sum_overload(x, h6, k1, k2, k3, k4):
    return _tuple_impl("x, h6, k1, k2, k3, k4", len(x),
                       lambda i: f"x[{i}] + h6 * (k1[{i}] + 2.0 * k2[{i}] + 2.0 * k3[{i}] + k4[{i}])")


def _select(keep, a, x):
    """``a if keep else x`` elementwise for tuples (compiled: a select, no branch)."""
    return tuple(a) if keep else tuple(x)


@overload(_select, jit_options=dict(nogil=True, error_model="numpy"))
def _select_overload(keep, a, x):
    return _tuple_impl("keep, a, x", len(x), lambda i: f"a[{i}] if keep else x[{i}]")


def _all_finite(x):
    """Whether every element of the tuple ``x`` is finite."""
    return all(math.isfinite(v) for v in x)


@overload(_all_finite, jit_options=dict(nogil=True, error_model="numpy"), inline="always")
def _all_finite_overload(x):
    return _generated("impl", "x", ["return " + " & ".join(f"math.isfinite(x[{i}])"
                                                           for i in range(len(x)))])


# ----------------------------------------------------------------------------
# The right-hand side of a plant kind, and one RK4 step of one lane
# ----------------------------------------------------------------------------
def plant_rhs(kind, p, c, x, u, sc):
    """The right-hand side of plant ``kind`` for one lane: the one place a kind becomes its function.

    In compiled code the *type* of ``kind`` selects the function at
    compile time (:data:`plant.simulation.plants.RIGHT_HAND_SIDES` maps kind classes to
    functions), so that a kernel compiles the right-hand side of its own
    plant and no other.

    Parameters
    ----------
    kind : NamedTuple
        A plant's :attr:`~plant.simulation.plants.Plant.kind`.
    p, c, x, u, sc
        As the right-hand sides of :mod:`plant.simulation.plants` (module docstring):
        parameters (n_par,), rig layout, state (n_x,), held currents (n_u,)
        and sin/cos of the m angles (2 m,).

    Returns
    -------
    (tuple of n_x float, float)
        The state derivative and the positive-definiteness margin.

    Raises
    ------
    numba.core.errors.TypingError
        At compile time, for a kind that is not registered.
    KeyError
        Called from Python, for a kind that is not registered.
    """
    return RIGHT_HAND_SIDES[type(kind)].function(p, c, x, u, sc)


@overload(plant_rhs, inline="always", jit_options=dict(nogil=True, error_model="numpy"))
def _plant_rhs_overload(kind, p, c, x, u, sc):
    rhs = _registered(kind).function

    def impl(kind, p, c, x, u, sc):
        return rhs(p, c, x, u, sc)

    return impl


@numba.njit(nogil=True, error_model="numpy", inline="always")  # IR-inlined into the lane loop
def rk4_lane(kind, p, c, x, u, a, hh, h, h6, exact):
    """One classical RK4 step of one lane from state ``x`` with held currents ``u``.

    The stages take sin/cos of the angles by angle addition from the lane's
    anchors ``a`` (:func:`plant.simulation.anchors.lane_sincos`); with ``exact`` a stage
    further than :data:`~plant.simulation.anchors.SINCOS_RANGE` from the anchors takes
    them from libm instead.

    Parameters
    ----------
    kind : NamedTuple
        Plant kind.
    p : tuple of n_par float
        The lane's plant parameters (:func:`lane_parameters`).
    c : NamedTuple
        Rig layout (:class:`plant.logs.rig.RigConstants`).
    x : tuple of n_x float
        State at the step's start.
    u : tuple of n_u float
        Held motor currents (A).
    a : tuple of 3 m float
        The lane's anchors (per angle: q, sin q, cos q).
    hh, h, h6 : float
        Half step, step and step / 6 (s).
    exact : bool
        Use libm for stages far from the anchors (else report them).

    Returns
    -------
    x_next : tuple of n_x float
        State after the step.
    ok : bool
        Positive-definiteness margin > 0 at all four stages.
    near : bool
        All four stages within range of the anchors (always reported, also
        with ``exact``).
    """
    sc, n1 = lane_sincos(x, a, exact)
    k1, m1 = plant_rhs(kind, p, c, x, u, sc)
    x2 = _axpy(x, hh, k1)
    sc, n2 = lane_sincos(x2, a, exact)
    k2, m2 = plant_rhs(kind, p, c, x2, u, sc)
    x3 = _axpy(x, hh, k2)
    sc, n3 = lane_sincos(x3, a, exact)
    k3, m3 = plant_rhs(kind, p, c, x3, u, sc)
    x4 = _axpy(x, h, k3)
    sc, n4 = lane_sincos(x4, a, exact)
    k4, m4 = plant_rhs(kind, p, c, x4, u, sc)
    ok = (m1 > 0.0) & (m2 > 0.0) & (m3 > 0.0) & (m4 > 0.0)
    return _rk4_sum(x, h6, k1, k2, k3, k4), ok, n1 & n2 & n3 & n4


@_jit
def _rk4_lane_exact(kind, p, c, x, u, a, hh, h, h6):
    """:func:`rk4_lane` with libm for far stages (a compiled call: rare lanes only)."""
    return rk4_lane(kind, p, c, x, u, a, hh, h, h6, True)


@numba.njit(nogil=True, error_model="numpy", inline="always")  # IR-inlined (plant.simulation.core)
def advance_sample(kind, P, c, X, U, A, S, W, n, substeps, reanchor):
    """Advance lanes ``0..n-1`` over one sample with the held currents ``U``.

    Classical 4th-order Runge-Kutta with ``substeps`` equal steps over
    ``Ts = c.sample_time_s`` of the plant's right-hand side (see the module
    docstring for its signature); the currents are held constant over the
    sample (zero-order hold, as the rig's amplifiers do).  Each step is one
    loop over the lanes (SIMD) with the lane's state in registers
    (:func:`rk4_lane`); a lane whose stages moved further than
    :data:`~plant.simulation.anchors.SINCOS_RANGE` from its anchors is left untouched
    there and stepped again with libm sin/cos (rare).

    Parameters
    ----------
    kind : NamedTuple
        The plant (:attr:`plant.simulation.plants.Plant.kind`); its right-hand side is
        chosen by :func:`plant_rhs`.
    P : ndarray, shape (n_par, lanes)
        Per-lane plant parameters (column j: lane j).
    c : plant.logs.rig.RigConstants
        Rig layout.
    X : ndarray, shape (n_x, lanes)
        State at the sample's start; advanced in place.
    U : ndarray, shape (n_u, lanes)
        Motor currents (A) held over the sample.
    A : ndarray, shape (3 m, lanes)
        Trigonometric anchors (:mod:`plant.simulation.anchors`); updated in place.
    S : ndarray, shape (lanes,), int64
        Status per lane: set to :data:`STATUS_NOT_PD` (the lane keeps the
        state of the step's start) or :data:`STATUS_NONFINITE` on failure (a
        lane already failed keeps its code).
    W : ndarray, shape (lanes,), int64
        Scratch from :func:`new_workspace`.
    n : int
        Number of lanes to advance (columns ``0..n-1``).
    substeps : int
        RK4 steps per sample (>= 1).
    reanchor : bool
        Take the anchors' sin/cos from libm at this sample.
    """
    h = c.sample_time_s / substeps
    hh = 0.5 * h
    h6 = h * (1.0 / 6.0)
    anchors_update(kind, X, A, n, reanchor)
    for _ in range(substeps):
        far = 0
        for j in range(n):  # SIMD over the lanes
            x = lane_state(kind, X, j)
            xn, ok, near = rk4_lane(kind, lane_parameters(kind, P, j), c, x, lane_inputs(kind, U, j),
                                    lane_anchors(kind, A, j), hh, h, h6, False)
            store_lane_state(X, j, _select(ok & near, xn, x))
            W[j] = _LANE_DONE if ok else _LANE_NOT_PD
            if not near:
                W[j] = _LANE_FAR
            far += not near
        if far:  # lanes whose stages left the anchors' range: again, with libm (rare)
            for j in range(n):
                if W[j] == _LANE_FAR:
                    x = lane_state(kind, X, j)
                    xn, ok, _ = _rk4_lane_exact(kind, lane_parameters(kind, P, j), c, x,
                                                lane_inputs(kind, U, j), lane_anchors(kind, A, j),
                                                hh, h, h6)
                    store_lane_state(X, j, _select(ok, xn, x))
                    W[j] = _LANE_DONE if ok else _LANE_NOT_PD
        for j in range(n):
            if W[j] == _LANE_NOT_PD and S[j] == STATUS_OK:
                S[j] = STATUS_NOT_PD
    for j in range(n):
        if S[j] == STATUS_OK and not _all_finite(lane_state(kind, X, j)):
            S[j] = STATUS_NONFINITE


def hold_and_advance(kind, lanes, c, substeps, k, i):
    """Hold the currents ``i`` (n,) and advance lane 0 over sample ``k``; returns the status.

    The closed loop's sample step (:func:`plant.simulation.closed_loop.simulate_closed_loop`
    compiles it for the PUMA 560 plants; a robot model's arm compiles a copy for its
    kind, :attr:`plant.simulation.arm.ArmPlant.kernels`).

    Parameters
    ----------
    kind : NamedTuple
        The plant's kind (its type selects the right-hand side, :func:`plant_rhs`).
    lanes : plant.simulation.lanes.Lanes
        The lanes ``(P, X, U, A, S, E, idx, W)``: parameters, state, inputs, anchors,
        status, ...; lane 0 is advanced.
    c : NamedTuple
        The rig constants (:func:`plant.logs.rig.rig_constants`).
    substeps : int
        RK4 steps over the sample.
    k : int
        The sample's index (every ``plant.simulation.anchors.REANCHOR``-th re-anchors
        the angles).
    i : ndarray, shape (n,)
        The motor currents held over the sample (A).

    Returns
    -------
    int
        Lane 0's status (:data:`STATUS_OK` or a failure code).
    """
    P, X, U, A, S, E, idx, W = lanes
    for m in range(U.shape[0]):
        U[m, 0] = i[m]
    advance_sample(kind, P, c, X, U, A, S, W, 1, substeps, k % REANCHOR == 0)
    return S[0]
