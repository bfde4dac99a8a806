"""Compiled control laws in the logged-run driver: the controller that ran, in the loop.

The logged-run driver (``plant.simulation.simulate.log_chunk``) simulates a
window or a run *with the controller that actually ran*.  As the plants of
the core (``plant.simulation.plants``), a control law is found by a *kind* (a type
tag whose numba type selects the law at compile time) in the registry
:data:`CONTROL_LAWS`; the driver calls :func:`control_law`, so each kernel is
compiled once per (plant, law) with only that law, loads from numba's cache,
and is not a copy of the sample loop.

A compiled law has the signature ``law(lp, c, k, Y, E, CS, U, j)``: law
parameters ``lp`` (any numba-typed value, e.g. a NamedTuple of constants and
arrays), the rig layout ``c`` (:class:`plant.logs.rig.RigConstants`), the
absolute sample index ``k`` (t = k Ts from the start of the run), the
measured joint angles ``Y`` (n_joints, lanes) (rad, the encoder counts times
2 pi / kN) and the pulse errors ``E`` (n_joints, lanes) of every lane, and
the per-lane controller state ``CS`` (n_cs, lanes); column ``j`` is this
lane's.  It writes the motor currents (A) held over the sample to ``U[:,
j]`` (n_joints, lanes) and updates ``CS[:, j]`` in place; the driver then
clips the currents at the drive's full scale.  A law written for a fixed
number of joints says so (:attr:`LoggedController.n_joints`; the PUMA 560
CTC laws: 2), and the drivers refuse it on a robot of another count.  Arrays
are joint-first here, as the core's lane arrays (one joint's lanes are
contiguous, for SIMD).

:data:`P_LAW` is the rig's P law ``i = P e`` (the logged experiment of the
paper); the driver computes its current inside its joint loop
(:func:`is_p_law`, :func:`p_current`: the identification's hot loop), bit
for bit what :func:`p_law` gives.  Another package provides its law by
registering it (``register_control_law(MyKind, my_law)``) and describing it
by a :class:`LoggedController`; :class:`ctc.ComputedTorqueController` does
so (:meth:`~ctc.ComputedTorqueController.logged_controller`), keeping
``plant`` independent of ``ctc``.  A law whose kind class is defined outside
the library (a user's script) runs in an in-memory twin of the driver
(:func:`plant.simulation.simulate.for_kinds`), so the on-disk cache never
holds a class another process cannot import.  A law that calls a large
compiled function is best declared ``inline="always"`` (as
:func:`ctc.computed_torque.ctc_law`): the lane arrays are then not passed
(and reference-counted) on every call.

Replay (:func:`plant.prediction_errors`) drives the model with the logged
input: ``i = P e_log`` for the P law (exact), the logged currents ``i_A``
for any other law (a controller records what it applied).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple

import numba
import numpy as np
from numba import types
from numba.core.errors import TypingError
from numba.extending import overload

__all__ = ["PLawKind", "P_LAW", "LoggedController", "CONTROL_LAWS", "register_control_law",
           "control_law", "p_law", "p_current", "is_p_law"]


class PLawKind(NamedTuple):
    """Type tag of the rig's P law ``i = P e`` (its numba type selects the law).

    Attributes
    ----------
    code : int
        0 (informative only: the *type* is what the driver dispatches on).
    """

    code: int = 0


@numba.njit(nogil=True, error_model="numpy", inline="always")
def p_current(c, m, e):
    """The rig's P current ``P e`` of joint ``m`` for the pulse error ``e`` (A, before the clip).

    Parameters
    ----------
    c : plant.logs.rig.RigConstants
        Rig layout (``p_gain``, A per pulse).
    m : int
        Joint (0-based).
    e : float
        Pulse error.

    Returns
    -------
    float
    """
    return c.p_gain[m] * e


def is_p_law(kind) -> bool:
    """True when ``kind`` is the rig's P law's (a compile-time constant in compiled code).

    The logged-run driver computes the P law's current inside its joint loop
    (:func:`p_current`, the identification's hot loop) instead of calling the
    law with the measured angles and errors of every lane.

    Parameters
    ----------
    kind : NamedTuple
        A :attr:`LoggedController.kind`.
    """
    return type(kind) is PLawKind


@overload(is_p_law, jit_options=dict(nogil=True), inline="always")
def _is_p_law_overload(kind):
    value = getattr(kind, "instance_class", None) is PLawKind

    def impl(kind):
        return value

    return impl


@numba.njit(nogil=True, error_model="numpy", inline="always")  # IR-inlined into the lane loop
def p_law(lp, c, k, Y, E, CS, U, j):
    """The rig's P law ``i = P e`` with the rig's gains (``lp`` unused).

    Parameters
    ----------
    lp : float
        Unused.
    c : plant.logs.rig.RigConstants
        Rig layout (``p_gain``).
    k : int
        Sample index.
    Y : ndarray, shape (n_joints, lanes)
        Measured angles (unused).
    E : ndarray, shape (n_joints, lanes)
        Pulse errors.
    CS : ndarray
        Controller state (unused).
    U : ndarray, shape (n_joints, lanes)
        Currents (A): column ``j`` is written.
    j : int
        Lane.
    """
    for m in range(U.shape[0]):
        U[m, j] = p_current(c, m, E[m, j])


#: Registry of the logged-run driver: law kind class -> compiled law
#: (:func:`register_control_law`).
CONTROL_LAWS = {}


def register_control_law(kind_class, law) -> None:
    """Register a compiled control law under its kind class (as :func:`plant.simulation.plants.register_plant`).

    Parameters
    ----------
    kind_class : type
        A ``NamedTuple`` class whose instances tag the law
        (:attr:`LoggedController.kind`).
    law : numba dispatcher
        ``law(lp, c, k, Y, E, CS, U, j)``, writing lane ``j``'s currents to
        ``U[:, j]`` (see the module docstring).

    Raises
    ------
    ValueError
        If ``kind_class`` is not a NamedTuple class or is registered to
        another law already.
    """
    if not (isinstance(kind_class, type) and issubclass(kind_class, tuple)
            and hasattr(kind_class, "_fields")):
        raise ValueError(f"a control-law kind must be a NamedTuple class, got {kind_class!r}")
    if CONTROL_LAWS.get(kind_class, law) is not law:
        raise ValueError(f"{kind_class.__name__} is registered to another control law")
    CONTROL_LAWS[kind_class] = law


register_control_law(PLawKind, p_law)


def control_law(kind, lp, c, k, Y, E, CS, U, j):
    """The control law of ``kind``: the one place a law kind becomes its function.

    In compiled code the kind's type selects the law at compile time (the
    pattern of ``plant.simulation.core.plant_rhs``); called from Python it looks the law
    up in :data:`CONTROL_LAWS` (a ``KeyError`` for an unregistered kind).

    Parameters
    ----------
    kind : NamedTuple
        A :attr:`LoggedController.kind`, registered in :data:`CONTROL_LAWS`.
    lp, c, k, Y, E, CS, U, j
        As the laws of the module docstring (lane ``j``'s currents go to
        ``U[:, j]``).

    Raises
    ------
    numba.core.errors.TypingError
        At compile time, for a kind that is not registered.
    """
    return CONTROL_LAWS[type(kind)](lp, c, k, Y, E, CS, U, j)


@overload(control_law, jit_options=dict(nogil=True, error_model="numpy"), inline="always")
def _control_law_overload(kind, lp, c, k, Y, E, CS, U, j):
    law = CONTROL_LAWS.get(getattr(kind, "instance_class", None))
    if not isinstance(kind, types.BaseNamedTuple) or law is None:
        raise TypingError(f"unknown control-law kind {kind}; register it in "
                          "plant.simulation.controllers.CONTROL_LAWS")

    def impl(kind, lp, c, k, Y, E, CS, U, j):
        return law(lp, c, k, Y, E, CS, U, j)

    return impl


@dataclass(frozen=True)
class LoggedController:
    """A compiled control law for the logged-run driver, with its parameters and state.

    Attributes
    ----------
    kind : NamedTuple
        Type tag registered in :data:`CONTROL_LAWS`.
    parameters : object
        The law's parameters ``lp`` (numba-typed value).
    state : ndarray, shape (n_cs,)
        Controller state at the log's first simulated sample (every lane
        starts from it).
    name : str
        For messages.
    n_joints : int or None
        The joints the law writes currents for (None: any number, e.g. a
        law that loops over ``U.shape[0]``); a driver refuses a robot of
        another joint count (:meth:`check_joints`).
    n_samples : int or None
        The samples from t = 0 the law's tables cover (e.g. its reference;
        None: any run); a driver refuses a longer run (:meth:`check_samples`).
    state_at : int or None
        The sample the start state belongs to (None: whichever sample the
        run starts at, e.g. a law without state); a driver refuses a run that
        starts elsewhere (:meth:`check_start`).
    driver : numba dispatcher or None
        A copy of the logged-run driver compiled with this law (None: the
        robot's own).  A law generated per robot
        (:meth:`ctc.arm.ArmComputedTorque.logged_controller`) lives in a
        generated module of its own with its own copy of the driver, so the
        on-disk cache of a driver never names a law kind of another
        generated module (which may have been pruned).
    """

    kind: Any
    parameters: Any
    state: np.ndarray
    name: str = "controller"
    n_joints: Any = None
    n_samples: Any = None
    state_at: Any = None
    driver: Any = None

    def check_joints(self, n) -> None:
        """Refuse a robot of ``n`` joints when the law writes another number of currents.

        Parameters
        ----------
        n : int
            The simulated robot's joints.

        Raises
        ------
        ValueError
            If :attr:`n_joints` is set and is not ``n``.
        """
        if self.n_joints is not None and int(self.n_joints) != int(n):
            raise ValueError(f"the {self.name} law writes {self.n_joints} joints' currents, "
                             f"the robot has {n}")

    def check_samples(self, n) -> None:
        """Refuse a run of ``n`` samples beyond the law's tables.

        Parameters
        ----------
        n : int
            Samples from t = 0 the run takes.

        Raises
        ------
        ValueError
            If :attr:`n_samples` is set and smaller than ``n``.
        """
        if self.n_samples is not None and int(n) > int(self.n_samples):
            raise ValueError(f"the {self.name} law's tables cover {self.n_samples} samples, "
                             f"the run takes {n}")

    def check_start(self, k) -> None:
        """Refuse a run that starts at sample ``k`` when the start state belongs to another.

        Parameters
        ----------
        k : int
            The sample the simulation starts at (a window's first with a given
            plant state, else 0).

        Raises
        ------
        ValueError
            If :attr:`state_at` is set and is not ``k``.
        """
        if self.state_at is not None and int(k) != int(self.state_at):
            raise ValueError(f"the {self.name} law starts from its state at sample "
                             f"{self.state_at}, the run at sample {k}: simulate the window "
                             "from t = 0 (no initial_state)")

    @property
    def is_p_law(self) -> bool:
        """True for the rig's P law (replay with ``P e_log``)."""
        return type(self.kind) is PLawKind

    def lane_states(self, lanes) -> np.ndarray:
        """Per-lane controller state (n_cs, lanes), every column the start state.

        Parameters
        ----------
        lanes : int
        """
        s = np.ascontiguousarray(self.state, dtype=np.float64).reshape(-1)
        return np.ascontiguousarray(np.tile(s[:, None], (1, lanes)))


#: The rig's P law (no parameters, no state).
P_LAW = LoggedController(kind=PLawKind(), parameters=0.0, state=np.zeros(1), name="P")


def as_logged_controller(controller, log) -> LoggedController:
    """The compiled law of ``controller`` for ``log`` (None: the rig's P law).

    Parameters
    ----------
    controller : LoggedController, object with ``logged_controller(log)``, or None
        E.g. a :class:`ctc.ComputedTorqueController`.
    log : plant.ExperimentLog

    Returns
    -------
    LoggedController

    Raises
    ------
    ValueError
        If ``controller`` provides no compiled law.
    """
    if controller is None:
        return P_LAW
    if isinstance(controller, LoggedController):
        return controller
    make = getattr(controller, "logged_controller", None)
    if make is None:
        raise ValueError(f"{type(controller).__name__} provides no compiled law for the logged "
                         "run (a logged_controller(log) method returning a "
                         "plant.simulation.controllers.LoggedController)")
    return make(log)
