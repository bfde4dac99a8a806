"""Synthetic rig logs: emulate the logged P-control experiment with the library's plant.

:func:`emulate_log` runs the rig's card -- encoder read, ``i = P e`` held over
the sample -- against the rigid or the two-mass flexible plant of
:mod:`plant.simulation.plants` through the one closed-loop core
(:func:`plant.simulate_closed_loop`, converged RK4 substeps), and returns an
:class:`~plant.logs.log.ExperimentLog` with the same CSV columns and a sidecar
synced to its rig and trajectory, ready to :meth:`~plant.logs.log.ExperimentLog.save`.
Change the rig (encoders, gear, gains, friction) with
:func:`dataclasses.replace` on a :class:`~plant.logs.rig.Rig`, the reference with a
:class:`~plant.logs.trajectory.Trajectory`, the robot with f (a payload:
:func:`plant.add_payload`) and the plant (flexible joints).

It is how the project makes *held-out* logs at settings other than the
development logs' (identification accuracy over many rigs, coverage of the
uncertainty estimates), and how the tests make logs with a known answer.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from plant.logs.arm_log import ArmLog, column_names, robot_section
from plant.logs.rig import p_law_current
from plant.logs.sidecar import rig_into_sidecar
from plant.simulation.arm import simulate_arm
from plant.simulation.closed_loop import simulate_closed_loop

__all__ = ["emulate_log", "emulate_arm_log"]

#: RK4 substeps of an emulated log (the pulses converge from 48; see plant.simulation.simulate).
EMULATION_SUBSTEPS = 64


class CardPLaw:
    """The rig card's P law ``i = P e`` (the sampled-controller protocol)."""

    def __init__(self, p_gain):
        self.p = np.asarray(p_gain, dtype=float)

    def reset(self):
        """Stateless."""

    def __call__(self, k, t, q_meas, e_pulses):
        return self.p * e_pulses


def emulate_log(base, f, *, rig=None, trajectory=None, duration_s=None, flexible=None,
                current_noise_A=0.0, rng=None, name=None, substeps=EMULATION_SUBSTEPS):
    """Emulate a P-control experiment and return it as a log.

    Parameters
    ----------
    base : plant.ExperimentLog
        Template: sidecar keys not set here (search ranges, notes) come from
        it, and its rig and trajectory are the defaults.
    f : array_like, shape (9,)
        The robot's base parameters (rigid-equivalent for a flexible plant).
    rig : plant.logs.rig.Rig, optional
        Rig constants (default ``base.rig``); its start state starts the run.
    trajectory : plant.logs.trajectory.Trajectory, optional
        Reference (default ``base.trajectory``).
    duration_s : float, optional
        Length of the run (default: ``base``'s), ``n = round(duration / Ts) + 1``
        samples from t = 0.
    flexible : plant.simulation.plants.FlexibleJoints, optional
        Emulate two-mass flexible joints instead of the rigid robot.
    current_noise_A : float
        Standard deviation of white noise added to the *logged* currents (A);
        the applied current stays ``P e`` (as in the development logs).
    rng : numpy.random.Generator or int, optional
        Random source of the current noise.
    name : str, optional
        The log's name (default ``base.name + "_emulated"``).
    substeps : int
        RK4 substeps per sample of the emulation.

    Returns
    -------
    plant.ExperimentLog
        A full run (``start_index`` 0); its ``path`` is the template's
        directory with the new name (nothing is written: call ``save``).

    Raises
    ------
    ValueError
        On bad shapes or values, or when the emulated robot fails (D(q) not
        positive definite, divergence).
    """
    rig = base.rig if rig is None else rig
    trajectory = base.trajectory if trajectory is None else trajectory
    ts = rig.sample_time_s
    if duration_s is None:
        n = base.n_total
    else:
        if not np.isfinite(duration_s) or duration_s <= 0:
            raise ValueError(f"duration_s must be a positive number, got {duration_s!r}")
        n = int(round(float(duration_s) / ts)) + 1
    if not current_noise_A >= 0:
        raise ValueError(f"current_noise_A must be >= 0, got {current_noise_A!r}")
    resp = simulate_closed_loop(rig, f, CardPLaw(rig.p_gain_A_per_pulse), trajectory=trajectory,
                                n_samples=n, substeps=substeps, flexible=flexible,
                                label="emulated P experiment")
    if not resp.success:
        raise ValueError(f"the emulated robot failed: {resp.message}")
    i_log = resp.i_A
    if current_noise_A > 0:
        i_log = i_log + np.random.default_rng(rng).normal(0.0, current_noise_A, i_log.shape)
    name = base.name + "_emulated" if name is None else str(name)
    # the sidecar is synced to the new rig, trajectory and length (ExperimentLog.replace)
    return base.replace(
        path=base.path.with_name(name + ".csv"), name=name, t=resp.t, q_ref=resp.q_ref,
        e_pulses=resp.e_pulses, i_A=i_log, rig=dataclasses.replace(rig), trajectory=trajectory,
        start_index=0, window_s=None)


def emulate_arm_log(plant, beta, rig, trajectory, n_samples, *, name="emulated", substeps=32,
                    robot=None) -> ArmLog:
    """A log of the rig's P-control experiment, made by the library's plant (:mod:`plant.simulation.arm`).

    For tutorials and tests of the file format.  Acceptance evidence comes
    from logs of an independent simulator (``benchmarks/independent_arm.py``).

    Parameters
    ----------
    plant : plant.simulation.arm.ArmPlant
        The robot.
    beta : array_like, shape (r,)
        Its true base parameters.
    rig : plant.Rig
    trajectory : plant.Trajectory
    n_samples : int
    name : str
    substeps : int
        RK4 steps per sample.
    robot : dict, optional
        The sidecar's ``robot`` object (default :func:`robot_section` of the
        plant's model).

    Returns
    -------
    ArmLog

    Raises
    ------
    ValueError
        If the simulation fails (D not positive definite, non-finite state).
    """
    sim = simulate_arm(plant, np.asarray(beta, dtype=float)[None], rig, trajectory, n_samples,
                       substeps=substeps)
    if sim.status[0] != 0:
        raise ValueError(f"the emulated run failed: {sim.message[0]}")
    e = sim.errors[0].astype(np.int64)
    t = np.arange(int(n_samples)) * rig.sample_time_s
    i = p_law_current(rig, e)
    sidecar = dict(dataset=name, robot=robot if robot is not None else robot_section(plant.model),
                   n_samples=int(n_samples))
    rig_into_sidecar(rig, sidecar)
    sidecar.update(trajectory=dict(parameters=trajectory.to_parameters()),
                   csv_columns={c: "" for c in column_names(plant.model.joint_names)})
    return ArmLog(path=None, name=name, model=plant.model, rig=rig, trajectory=trajectory, t=t,
                  q_ref=trajectory.position(t), e_pulses=e, i_A=i, sidecar=sidecar)
