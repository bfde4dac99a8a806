"""Rig constants of a PUMA 560 links 2-3 test set-up, read from a log's sidecar."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: Names of the nine base parameters, in order (paper eq. 3).
F_NAMES = ("f1", "f2", "f3", "f4", "f5", "f6", "f7", "f8", "f9")

#: SI units of f1..f9 (inertias kg m^2, first moments kg m).
F_UNITS = ("kg m^2", "kg m^2", "kg m^2", "kg m^2", "kg m", "kg m", "kg m^2", "kg m", "kg m")


@dataclass(frozen=True)
class Rig:
    """Constants of the drive, encoders and P controller of one experiment.

    All values come from the log's JSON sidecar; nothing is hard-coded.
    Per-joint values are ordered (joint 2, joint 3).

    Attributes
    ----------
    sample_time_s : float
        Controller sample time Ts (s).
    gear_ratio : tuple of 2 float
        k, defined by motor angle = k * joint angle (k3 < 0 on the PUMA).
    encoder_ppr : tuple of 2 int
        Motor-encoder pulses per motor revolution N.
    p_gain_A_per_pulse : tuple of 2 float
        P gain (A per pulse of error).
    torque_constant_Nm_per_A : tuple of 2 float
        Motor torque constant Kt.
    viscous_friction_Nms_per_rad : tuple of 2 float
        Motor-side viscous friction B (joint side: k^2 B).
    coulomb_friction_Nm : tuple of 2 (float, float)
        Motor-side Coulomb friction per joint, (magnitude for positive joint
        velocity, magnitude for negative joint velocity); joint side: abs(k) Tc.
    coulomb_ramp_speed_rad_per_s : float
        Motor speed below which the Coulomb friction ramps linearly to zero.
    gravity_m_s2 : float
        Gravitational acceleration g.
    a3_m : float
        Link length a3 (m).
    q0_rad, qd0_rad_per_s : tuple of 2 float
        Start state of the run (at t = 0).
    f_bounds : tuple of 9 (float, float)
        Search ranges (low, high) of f1..f9.
    current_full_scale_A : float or None
        Current saturation of the amplifiers, if the sidecar gives one.
    payload_mass_kg : float or None
        Payload mass if the sidecar states it, else None.
    """

    sample_time_s: float
    gear_ratio: tuple
    encoder_ppr: tuple
    p_gain_A_per_pulse: tuple
    torque_constant_Nm_per_A: tuple
    viscous_friction_Nms_per_rad: tuple
    coulomb_friction_Nm: tuple
    coulomb_ramp_speed_rad_per_s: float
    gravity_m_s2: float
    a3_m: float
    q0_rad: tuple = (0.0, 0.0)
    qd0_rad_per_s: tuple = (0.0, 0.0)
    f_bounds: tuple = ()
    current_full_scale_A: float | None = None
    payload_mass_kg: float | None = None

    @property
    def pulses_per_rad(self) -> np.ndarray:
        """Encoder pulses per joint radian, k N / (2 pi), shape (2,); negative for k < 0."""
        return np.array(
            [k * n / (2.0 * math.pi) for k, n in zip(self.gear_ratio, self.encoder_ppr)]
        )

    @property
    def bounds(self) -> np.ndarray:
        """Search ranges of f1..f9 as an array of shape (9, 2): columns (low, high)."""
        return np.array(self.f_bounds, dtype=float).reshape(9, 2)
