"""Computed-torque control of any serial arm from its identified base parameters.

The law of :mod:`ctc.computed_torque`, for the n joints of a robot model
(:class:`plant.robot_model.RobotModel`) whose base parameters beta were
identified (:func:`identification.arm.identify_arm`)::

    a   = qdd_d(t_k + Ts/2) + Kv (qd_d - qd_hat) + Kp (q_d - q_hat)       (outer loop)
    tau = D_hat(q_m) a + n_hat(q_m, qd_d(t_k + Ts/2)) - tau_f(qd_d(t_k + Ts/2))
    i   = clip(tau / (k Kt), -I_fs, I_fs)                                  (motor current)

with ``q_m = q_hat + q_d(t_k + Ts/2) - q_d(t_k)``: the feed-forward and the
model are taken at the middle of the sample over which the current is held
(zero-order hold), where the mean acceleration of the reference lies
(``qd_d(t_k + Ts) - qd_d(t_k) = Ts qdd_d(t_k + Ts/2) + O(Ts^3)``).  Measured:
on a PUMA 560 joints 1-3 draw with 4096-pulse encoders at 4.8 rad/s, the
feed-forward at ``t_k`` left 3-4 pulses of lag with the *true* parameters,
the mid-sample one +-1 (``benchmarks/independent_arm.py``, ``draw("puma123", 1)``).

* ``D_hat`` and ``n_hat`` (Coriolis/centrifugal plus gravity) are the
  robot model's, instantiated with beta: the same casadi expressions in the
  joints' sines and cosines that the plant of :mod:`plant.arm` compiles
  (Craig, *Introduction to Robotics*, sec. 10.5; Spong, Hutchinson &
  Vidyasagar, *Robot Modeling and Control*, sec. 8.3);
* ``tau_f`` the sidecar's drive friction (:func:`plant.model.friction_torque`),
  cancelled by feed-forward at the reference velocity;
* ``q_hat, qd_hat`` the current observer of :mod:`ctc.design` per joint
  (double integrator driven by the commanded acceleration, measurement at
  the centre of the count's cell);
* Kp, Kv and the observer gains by :func:`ctc.design.design_gains` per joint
  (default bandwidth :func:`ctc.design.default_bandwidth_hz`);
* the current is saturated at the drive's full scale; the observer is then
  driven by the acceleration the saturated current gives (no windup).

The controller follows the sampled-controller protocol (``reset()``,
``__call__(k, t, q_meas, e_pulses) -> (n,) A``), so
:func:`plant.simulate_closed_loop` (``plant=`` the arm) and the independent
simulator of ``benchmarks/`` run it; :class:`ctc.PController` is the rig's
P loop for any number of joints.
"""
from __future__ import annotations


import numpy as np

from plant.core import cell_centre
from plant.model import friction_torque
from plant.rig import rig_constants

from .design import gains_for

__all__ = ["ArmComputedTorque"]


class ArmComputedTorque:
    """Computed-torque controller of a robot model's arm with identified base parameters.

    Parameters
    ----------
    plant : plant.arm.ArmPlant
        The robot (:func:`plant.arm.arm_plant`); its base parameters define beta.
    beta : array_like, shape (r,)
        Base parameters of the controller's model (identified).
    rig : plant.Rig
        The rig (sample time, gears, encoders, Kt, friction, current limit).
    trajectory : plant.Trajectory
        Reference of the n joints.
    gains : ctc.design.GainDesign, optional
        Ready-made gains (default: :func:`ctc.design.design_gains` for the rig).
    **design
        Keywords of :func:`ctc.design.design_gains` (instead of ``gains``).

    Raises
    ------
    ValueError
        beta of the wrong size or not finite, a rig or trajectory with another
        joint count, or a model whose D_hat is not positive definite at the
        reference's start.
    """

    def __init__(self, plant, beta, rig, trajectory, *, gains=None, **design):
        from plant.arm import ArmPlant

        if not isinstance(plant, ArmPlant):
            raise ValueError(f"plant must be a plant.arm.ArmPlant, got {type(plant).__name__}")
        self.plant = plant
        self.n = plant.n_joints
        self.beta = plant.lane_parameters(beta)[:, 0].copy()
        c = rig_constants(rig, q0=np.zeros(self.n), qd0=np.zeros(self.n))
        if len(c.pulses_per_rad) != self.n:
            raise ValueError(f"the rig has {len(c.pulses_per_rad)} joints, the robot {self.n}")
        self.c = c
        self.trajectory = trajectory
        self.gains = gains_for(rig, gains, **design)
        if self.gains.estimator != "observer":
            raise ValueError("ArmComputedTorque uses the observer estimator")
        self.ts = c.sample_time_s
        self.spr = np.asarray(c.pulses_per_rad)
        self.torque_per_amp = np.asarray(c.torque_per_amp)
        self.limit = c.current_limit
        self._dyn = plant.dynamics_function
        q, _, _ = trajectory.evaluate(np.zeros(1))
        if np.asarray(q).shape != (1, self.n):
            raise ValueError(f"the trajectory has {np.asarray(q).shape[1]} joints, the robot {self.n}")
        D, _ = self.terms(q[0], np.zeros(self.n))
        if np.any(np.linalg.eigvalsh(D) <= 0):
            raise ValueError("the controller's D_hat(q) is not positive definite at the reference's start")
        self.reset()

    @classmethod
    def from_result(cls, result, log, **design):
        """The controller of an identification result on its log's rig and reference.

        Parameters
        ----------
        result : identification.arm.ArmIdentificationResult
        log : plant.arm_log.ArmLog
        **design
            As the constructor (``gains=`` or :func:`ctc.design.design_gains` keywords).

        Returns
        -------
        ArmComputedTorque

        Raises
        ------
        ValueError
            As the constructor, or a result that is not a success.
        """
        if not result.get("success", False):
            raise ValueError(f"the identification did not succeed: {result.get('message')}")
        # the result's rig: the log's, with the friction the identification found
        return cls(result["plant"], result["beta"], result["rig"], log.trajectory, **design)

    def terms(self, q, qd):
        """``D_hat(q)`` (n, n) and ``n_hat(q, qd)`` (n,) of the controller's model.

        Parameters
        ----------
        q, qd : array_like, shape (n,)
            Joint angles (rad) and rates (rad/s).

        Returns
        -------
        (ndarray, ndarray)
            Inertia matrix (kg m^2) and Coriolis/centrifugal plus gravity torques (N m).
        """
        q = np.asarray(q, dtype=float)
        sc = np.empty(2 * self.n)
        sc[0::2] = np.sin(q)
        sc[1::2] = np.cos(q)
        lower, nvec = self._dyn(sc, qd, self.beta)
        lower = np.asarray(lower).ravel()
        D = np.zeros((self.n, self.n))
        D[np.tril_indices(self.n)] = lower
        D = D + np.tril(D, -1).T
        return D, np.asarray(nvec).ravel()

    def reset(self):
        """Observer at the reference's start (the robot starts on it), no previous command."""
        q, qd, _ = self.trajectory.evaluate(np.zeros(1))
        self.x = np.vstack([q[0], qd[0]])  # rows: q_hat, qd_hat
        self.a_prev = np.zeros(self.n)

    def __call__(self, k, t, q_meas, e_pulses):
        """Motor currents (n,) A for sample ``k`` at time ``t`` (sampled-controller protocol)."""
        ts = self.ts
        count = np.rint(np.asarray(q_meas, dtype=float) * self.spr)
        y = np.array([cell_centre(v) for v in count]) / self.spr
        # current estimator: predict with the applied acceleration, correct with y
        q_p = self.x[0] + ts * self.x[1] + 0.5 * ts * ts * self.a_prev
        w_p = self.x[1] + ts * self.a_prev
        L = self.gains.observer_gain
        r = y - q_p
        self.x = np.vstack([q_p + L[:, 0] * r, w_p + L[:, 1] * r])
        (q_d, qd_d, _), (q_m, qd_m, qdd_m) = (
            [v[r] for v in self.trajectory.evaluate(np.array([t, t + 0.5 * ts]))] for r in (0, 1))
        a = qdd_m + self.gains.Kv * (qd_d - self.x[1]) + self.gains.Kp * (q_d - self.x[0])
        D, nv = self.terms(self.x[0] + (q_m - q_d), qd_m)
        tf = np.array([friction_torque(qd_m[j], self.c.viscous[j], self.c.coulomb_pos[j],
                                       self.c.coulomb_neg[j], self.c.ramp_speed[j])
                       for j in range(self.n)])
        tau = D @ a + nv - tf
        i = tau / self.torque_per_amp
        if np.any(np.abs(i) > self.limit):  # saturated: the observer sees what the drive gives
            i = np.clip(i, -self.limit, self.limit)
            a = np.linalg.solve(D, i * self.torque_per_amp - nv + tf)
        self.a_prev = a
        return i
