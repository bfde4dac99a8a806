"""Friction identified with f when the rig does not know it.

The paper (section 3): the drive constants "... if the last ones are unknown,
then they have to be included as unknown parameters".  A sidecar with
``"viscous_friction_Nms_per_rad": null`` and/or ``"coulomb_friction_Nm": null``
(:attr:`plant.logs.rig.Rig.unknown_friction`) makes :func:`identification.identify`
wrap its parameterisation in :class:`FrictionParameters`: the searched vector
is the wrapped one's followed by the unknown friction components (motor side,
the sidecar's units: viscous B per joint, Coulomb Tc per joint and sign of
the joint velocity), and the simulation runs the rigid plant with per-lane
friction (:data:`plant.simulation.friction.RIGID_FRICTION`).  Both the GA and the
refinement search them with f: the output error and the prediction errors
depend on the friction through the same simulation.

The search box of the friction comes from the log itself, not from a guess
about the drive: the largest motor torque the log applied, ``T = max |Kt
i|`` (per joint), gives ``0 <= Tc <= T`` and ``0 <= B <= T / w`` with ``w``
the largest motor speed of the reference (``|k| max |qd_ref|``).  That is a
scale, not a bound: gravity and inertia supply torque too, and an arm whose
weight drives a joint dissipates more than the drive applied.  So
:func:`identification.identify` widens this box where the refined fit ends
on its upper bound (as :func:`identification.arm.identify_arm` widens its
guessed box; the result's ``refinement['friction_box_widened']`` says
what), and a box given as ``friction_bounds`` is kept as it is.  The Coulomb
ramp speed is the rig's (from
``coulomb_ramp_speed_rad_per_s``, the ``coulomb_friction_note`` or a
documented default, :func:`plant.logs.sidecar.rig_from_sidecar`).
"""
from __future__ import annotations

import numpy as np

from plant.logs.rig import rig_constants
from plant.simulation.friction import FRICTION_NAMES, RIGID_FRICTION, friction_fields, friction_vector

from .parameters import BaseParameters, HeldModelChange, Parameterisation, check_bounds

__all__ = ["FrictionParameters", "FrictionChangeParameters", "unknown_friction_indices", "default_friction_bounds",
           "friction_entries", "full_friction", "FRICTION_COMPONENTS", "friction_layout",
           "joint_friction_columns"]


def unknown_friction_indices(rig) -> list:
    """Indices (into :data:`plant.simulation.friction.FRICTION_NAMES`) of the rig's unknown friction.

    Parameters
    ----------
    rig : plant.logs.rig.Rig

    Returns
    -------
    list of int
        0, 1 if the viscous friction is unknown; 2..5 if the Coulomb friction is.
    """
    idx = []
    if rig.viscous_friction_Nms_per_rad is None:
        idx += [0, 1]
    if rig.coulomb_friction_Nm is None:
        idx += [2, 3, 4, 5]
    return idx


def default_friction_bounds(log) -> np.ndarray:
    """Search box (6, 2) of the motor-side friction from the log (module docstring).

    Parameters
    ----------
    log : plant.ExperimentLog

    Returns
    -------
    ndarray, shape (6, 2)
        ``[0, T / w]`` for B2, B3 and ``[0, T]`` for the four Coulomb levels,
        with T the largest motor torque ``|Kt i|`` and w the largest motor
        speed ``|k qd_ref|`` of the log, per joint (a scale, not a bound:
        see the module docstring).

    Raises
    ------
    ValueError
        If the log applies no current or its reference does not move.
    """
    rig = log.rig
    kt = np.asarray(rig.torque_constant_Nm_per_A, dtype=float)
    k = np.abs(np.asarray(rig.gear_ratio, dtype=float))
    torque = kt * np.max(np.abs(np.asarray(log.i_A, dtype=float)), axis=0)
    t = np.arange(log.n_total) * rig.sample_time_s
    _, qd_ref, _ = log.trajectory.evaluate(t)
    speed = k * np.max(np.abs(qd_ref), axis=0)
    if not (np.all(torque > 0) and np.all(speed > 0)):
        raise ValueError("the friction cannot be identified from a log whose current or "
                         "reference speed is zero on a joint")
    hi = np.array([torque[0] / speed[0], torque[1] / speed[1],
                   torque[0], torque[0], torque[1], torque[1]])
    return np.column_stack([np.zeros(6), hi])


def full_friction(unknown_values, log) -> np.ndarray:
    """Motor-side friction vectors: the rig's known components, the unknown ones given.

    Parameters
    ----------
    unknown_values : array_like, shape (u,) or (m, u)
        Values of the rig's unknown components (:func:`unknown_friction_indices`
        order), u = their number (0 when the rig knows its friction).
    log : plant.ExperimentLog

    Returns
    -------
    ndarray, shape (6,) or (m, 6)
        In :data:`plant.simulation.friction.FRICTION_NAMES` order.
    """
    v = np.asarray(unknown_values, dtype=float)
    V = np.tile(friction_vector(log.rig), v.shape[:-1] + (1,))
    unknown = unknown_friction_indices(log.rig)
    if unknown:
        V[..., unknown] = v
    return V


def friction_entries(log) -> dict:
    """Result entries of a log whose friction is known: echoed from the sidecar.

    Parameters
    ----------
    log : plant.ExperimentLog

    Returns
    -------
    dict
        ``viscous_friction_Nms_per_rad`` (2), ``coulomb_friction_Nm`` (2 x 2)
        (unknown values as 0) and ``friction_identified`` False.
    """
    return dict(friction_fields(friction_vector(log.rig)), friction_identified=False)


class FrictionParameters(Parameterisation):
    """Another parameterisation plus the rig's unknown friction (motor side).

    ``x = [x_base, friction]``: the wrapped parameterisation's vector, then
    the unknown components of ``(B2, B3, Tc2+, Tc2-, Tc3+, Tc3-)`` (those the
    sidecar gives as null; the known ones stay the sidecar's).  The
    simulation is :data:`plant.simulation.friction.RIGID_FRICTION` with each
    candidate's friction.

    Parameters
    ----------
    base : Parameterisation, optional
        What is searched besides the friction (default
        :class:`~identification.parameters.BaseParameters`).
    friction_bounds : array_like, shape (6, 2), optional
        Box of the six friction components (rows of the known ones unused);
        default :func:`default_friction_bounds`.

    Raises
    ------
    ValueError
        On malformed bounds.
    """

    def __init__(self, base=None, friction_bounds=None):
        self.base = BaseParameters() if base is None else base
        if not isinstance(self.base, Parameterisation):
            raise ValueError("base must be an identification.Parameterisation")
        self._fb = None if friction_bounds is None else check_bounds(friction_bounds, 6)
        self.name = self.base.name + "+friction"

    def _k(self, log):
        return len(self.base.names(log))

    @property
    def friction_bounds(self):
        """The caller's friction box (6, 2), or None for the log's guess."""
        return None if self._fb is None else np.array(self._fb, dtype=float)

    def guessed(self, log) -> bool:
        """Whether the friction box is the log's guess (:func:`default_friction_bounds`).

        True when some friction component is unknown and no
        ``friction_bounds`` were given: :func:`identification.identify`
        then widens it where the fit ends on it.

        Parameters
        ----------
        log : plant.ExperimentLog
        """
        return self._fb is None and bool(unknown_friction_indices(log.rig))

    def names(self, log) -> list:
        """The wrapped names, then the unknown friction components.

        Parameters
        ----------
        log : plant.ExperimentLog
        """
        return list(self.base.names(log)) + [FRICTION_NAMES[i]
                                             for i in unknown_friction_indices(log.rig)]

    def bounds(self, log) -> np.ndarray:
        """The wrapped box, then the friction box rows of the unknown components.

        Parameters
        ----------
        log : plant.ExperimentLog
        """
        fb = default_friction_bounds(log) if self._fb is None else self._fb
        return np.vstack([self.base.bounds(log), fb[unknown_friction_indices(log.rig)]])

    def to_f(self, x, log) -> np.ndarray:
        """The wrapped parameterisation's f of the leading components.

        Parameters
        ----------
        x : ndarray, shape (k,) or (m, k)
        log : plant.ExperimentLog
        """
        x = np.asarray(x, dtype=float)
        return self.base.to_f(x[..., :self._k(log)], log)

    def friction(self, x, log) -> np.ndarray:
        """Full motor-side friction vectors (known from the rig, unknown from x).

        Parameters
        ----------
        x : ndarray, shape (k,) or (m, k)
        log : plant.ExperimentLog

        Returns
        -------
        ndarray, shape (6,) or (m, 6)
        """
        return full_friction(np.asarray(x, dtype=float)[..., self._k(log):], log)

    def plant(self, log):
        """:data:`plant.simulation.friction.RIGID_FRICTION`.

        Parameters
        ----------
        log : plant.ExperimentLog
        """
        return RIGID_FRICTION

    def plant_parameters(self, x, log):
        """``{"friction": (m, 6)}`` for candidates x (m, k).

        Parameters
        ----------
        x : ndarray, shape (m, k)
        log : plant.ExperimentLog
        """
        return {"friction": np.atleast_2d(self.friction(x, log))}

    def extras(self, x, log) -> dict:
        """The wrapped extras, the identified friction fields, ``friction_identified``.

        Parameters
        ----------
        x : ndarray, shape (k,)
        log : plant.ExperimentLog
        """
        out = dict(self.base.extras(np.asarray(x)[:self._k(log)], log))
        out.update(friction_fields(self.friction(x, log)), friction_identified=True)
        return out

    def refine_starts(self, log):
        """The wrapped starts with the friction at the middle of its box (or None: the GA's).

        Parameters
        ----------
        log : plant.ExperimentLog
        """
        s = self.base.refine_starts(log)
        if s is None:
            return None
        s = np.atleast_2d(np.asarray(s, dtype=float))
        fb = self.bounds(log)[self._k(log):]
        return np.hstack([s, np.tile(fb.mean(axis=1), (len(s), 1))])

    def initial_state(self, log):
        """The wrapped parameterisation's (see :meth:`Parameterisation.initial_state`).

        Parameters
        ----------
        log : plant.ExperimentLog
        """
        return self.base.initial_state(log)

    def __repr__(self) -> str:
        return f"FrictionParameters(base={self.base!r})"


class FrictionChangeParameters(HeldModelChange):
    """A change of the drive friction on a window, the robot's f held (the friction hypothesis).

    The rival of :class:`~identification.parameters.PayloadParameters` in the
    adaptive CTC's supervisor (:mod:`ctc.adaptive`, step 3): the window's
    change explained by friction instead of a payload.  It searches
    ``x = [dB2, dB3, dTc2, dTc3]``, motor side: the viscous coefficients
    become ``B + dB`` and both Coulomb levels of a joint ``Tc+- + dTc`` (four
    degrees of freedom, as many as the payload's ``m, xp, yp, Jc``, so the
    two hypotheses are compared by their output errors alone).  f is the
    model in use for every candidate; the plant is the window's (the rigid
    robot with per-lane friction, :data:`plant.simulation.friction.RIGID_FRICTION`,
    or the wrapped space's two-mass plant with its joints) with each
    candidate's friction.  The box keeps every total friction within the
    log's box (:func:`default_friction_bounds`: the scale of the largest
    motor torque the window applied) and non-negative.

    Parameters
    ----------
    space : Parameterisation
        The window's payload parameterisation (its plant, plant parameters
        and start state are used): :class:`~identification.parameters.PayloadParameters`
        or :class:`~identification.flexible.FlexiblePayloadParameters`.
    f : array_like, shape (9,)
        The model in use (rigid-equivalent base parameters f1..f9).

    Raises
    ------
    ValueError
        On an ``f`` that is not 9 finite numbers, or a ``space`` that is not a
        :class:`~identification.parameters.Parameterisation`.
    """

    name = "friction change"

    def names(self, log) -> list:
        """``['dB2', 'dB3', 'dTc2', 'dTc3']``.

        Parameters
        ----------
        log : plant.ExperimentLog
        """
        return ["dB2_Nms_per_rad", "dB3_Nms_per_rad", "dTc2_Nm", "dTc3_Nm"]

    def bounds(self, log) -> np.ndarray:
        """Box (4, 2) of the changes: every total in ``[0, the log's bound]``.

        Parameters
        ----------
        log : plant.ExperimentLog

        Raises
        ------
        ValueError
            If the window applies no current or its reference does not move
            on a joint (:func:`default_friction_bounds`).
        """
        v0 = friction_vector(log.rig)
        hi = default_friction_bounds(log)[:, 1]
        tc_lo = np.minimum(v0[[2, 4]], v0[[3, 5]])
        tc_hi = np.maximum(v0[[2, 4]], v0[[3, 5]])
        lo = np.concatenate([-v0[:2], -tc_lo])
        up = np.concatenate([np.maximum(hi[:2] - v0[:2], 0.0),
                             np.maximum(hi[[2, 4]] - tc_hi, 0.0)])
        return np.column_stack([lo, up])

    def friction(self, x, log) -> np.ndarray:
        """Motor-side friction vectors (:data:`FRICTION_NAMES` order) of the changes x.

        Parameters
        ----------
        x : ndarray, shape (4,) or (m, 4)
        log : plant.ExperimentLog

        Returns
        -------
        ndarray, shape (6,) or (m, 6)
        """
        x = np.asarray(x, dtype=float)
        v = np.broadcast_to(friction_vector(log.rig), x.shape[:-1] + (6,)).copy()
        v[..., 0:2] += x[..., 0:2]
        v[..., 2:4] += x[..., 2:3]
        v[..., 4:6] += x[..., 3:4]
        return np.maximum(v, 0.0)

    def plant(self, log):
        """The wrapped space's plant, or :data:`RIGID_FRICTION` for the rigid one.

        Parameters
        ----------
        log : plant.ExperimentLog
        """
        p = self.space.plant(log)
        return RIGID_FRICTION if p is None else p

    def plant_parameters(self, x, log):
        """The wrapped space's plant parameters and ``friction`` (m, 6).

        Parameters
        ----------
        x : ndarray, shape (m, k)
        log : plant.ExperimentLog
        """
        x = np.atleast_2d(np.asarray(x, dtype=float))
        out = dict(self.space.plant_parameters(x, log) or {})
        out["friction"] = self.friction(x, log)
        return out

    def extras(self, x, log) -> dict:
        """``friction_change``: the changes and the friction they give.

        Parameters
        ----------
        x : ndarray, shape (4,)
        log : plant.ExperimentLog
        """
        x = np.asarray(x, dtype=float)
        return dict(friction_change=dict(zip(self.names(log), (float(v) for v in x))),
                    **friction_fields(self.friction(x, log)))

    def refine_starts(self, log) -> np.ndarray:
        """No change, and the changes a quarter of the box up, down and crossed.

        Parameters
        ----------
        log : plant.ExperimentLog
        """
        b = self.bounds(log)
        z = np.zeros(4)
        span = b[:, 1] - b[:, 0]
        starts = np.array([z, z + 0.25 * span, z - 0.25 * span,
                           z + 0.25 * span * np.array([1.0, 1.0, -1.0, -1.0])])
        return np.clip(starts, b[:, 0], b[:, 1])


#: Joint-side friction components of a joint, in the lane order of
#: :func:`plant.simulation.arm.arm_plant` (``lane_friction``).
FRICTION_COMPONENTS = ("viscous", "coulomb_pos", "coulomb_neg")


def joint_friction_columns(qd, ramp_speed, unknown) -> np.ndarray:
    """Regressor columns of the unknown joint-side friction components along the states.

    The drive friction is linear in its constants: ``v qd`` (viscous),
    ``Tc+ r [qd > 0]`` and ``Tc- r [qd <= 0]`` (Coulomb) with the rig's
    ramp ``r = clip(qd / v_ramp, -1, 1)`` (:func:`plant.robot.model.friction_torque`
    up to its sign); an identification that does not know them estimates
    them with the base parameters (the paper: "if unknown, have to be
    included as unknown parameters").

    Parameters
    ----------
    qd : ndarray, shape (m, n)
        Joint rates (rad/s), time-first.
    ramp_speed : array_like, shape (n,)
        The Coulomb ramp's speed per joint (rad/s, joint side).
    unknown : sequence of (int, int)
        ``(joint, component)`` pairs of :func:`friction_layout` (0 viscous,
        1 Coulomb +, 2 Coulomb -).

    Returns
    -------
    ndarray, shape (m, n, len(unknown))
        Column k is nonzero on its joint's row only.
    """
    qd = np.asarray(qd, dtype=float)
    n = qd.shape[1]
    r_ = np.clip(qd / np.asarray(ramp_speed, dtype=float), -1.0, 1.0)
    cols = np.zeros((qd.shape[0], n, len(unknown)))
    for k, (j, what) in enumerate(unknown):
        cols[:, j, k] = (qd[:, j] if what == 0 else
                         r_[:, j] * (qd[:, j] > 0) if what == 1 else r_[:, j] * (qd[:, j] <= 0))
    return cols


def friction_layout(rig):
    """The rig's known joint-side friction (n, 3) and its unknown components.

    Parameters
    ----------
    rig : plant.Rig

    Returns
    -------
    known : ndarray, shape (n, 3)
        Joint-side viscous, Coulomb +, Coulomb - (zero where unknown).
    unknown : list of (int, int)
        ``(joint, component)`` of each unknown value (component 0 viscous,
        1 Coulomb +, 2 Coulomb -), in the order they follow beta.
    """
    c = rig_constants(rig)
    known = np.column_stack([c.viscous, c.coulomb_pos, c.coulomb_neg])
    comps = ([0] if rig.viscous_friction_Nms_per_rad is None else []) + \
        ([1, 2] if rig.coulomb_friction_Nm is None else [])
    unknown = [(j, w) for j in range(known.shape[0]) for w in comps]
    return known, unknown
