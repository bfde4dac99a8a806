"""Physical sanity of an experiment's signals before anything is identified from it.

:func:`plant.load_log` checks that a log is well formed (columns, numbers,
times, sidecar keys).  A well-formed log can still be meaningless: too short
for the parameters asked of it, a robot at rest, an encoder count that no
encoder could produce, currents that are not the drive's, or error columns
that disagree with the rig's own control law ``i = P e`` (paper, sec. 2: the
control card computes the current from the integer error).  Identifying such
a log returns numbers that look like a result; :func:`check_experiment`
refuses it with one line instead (issue 22).

Every rule is a physical bound, not a threshold fitted to data:

* **length** -- at least :data:`SAMPLES_PER_PARAMETER` samples per searched
  parameter and :data:`MIN_SAMPLES` in all (the output error of eq. 4 must
  outnumber its unknowns many times over);
* **signal** -- not every error and current zero;
* **encoder range** -- ``|e| <= (max |q_ref| + 2 pi) N k / (2 pi)``: the arm
  is never a whole joint turn past the farthest reference;
* **encoder rate** -- a change of the error between two samples of at most
  ``(max |qd_ref| + MAX_JOINT_SPEED) Ts N |k| / (2 pi) + 2`` pulses;
* **currents** -- ``|i| <= CURRENT_FACTOR x`` the drive's full scale (or
  :data:`MAX_CURRENT_A` when the sidecar gives none);
* **control law** -- for a P-control log with logged currents, the RMS of
  ``i - sat(P e)`` at most ``P_LAW_RELATIVE x RMS(sat(P e)) + P_LAW_NOISE_A``
  per joint, over the samples where ``|P e|`` does not exceed the largest
  logged current (a limit the sidecar does not state clips the others)
  (current noise of up to 0.1 A, the suite's widest, passes; swapped error
  columns or a wrong P gain do not).
"""
from __future__ import annotations

import math

import numpy as np

from plant._errors import LogError

__all__ = ["check_experiment", "MIN_SAMPLES", "SAMPLES_PER_PARAMETER", "MAX_JOINT_SPEED",
           "CURRENT_FACTOR", "MAX_CURRENT_A", "P_LAW_RELATIVE", "P_LAW_NOISE_A"]

#: Fewest samples of any identification.
MIN_SAMPLES = 50
#: Fewest samples per searched parameter.
SAMPLES_PER_PARAMETER = 10
#: Joint speed (rad/s) beyond the reference's that no arm of this class reaches.
MAX_JOINT_SPEED = 50.0
#: Logged currents beyond this multiple of the drive's full scale are not the drive's.
CURRENT_FACTOR = 10.0
#: The current bound (A) when the sidecar has no full scale.
MAX_CURRENT_A = 1e4
#: Relative RMS mismatch of ``i`` against ``P e`` tolerated (plus the noise allowance).
P_LAW_RELATIVE = 0.3
#: Absolute RMS allowance (A) for current measurement noise.
P_LAW_NOISE_A = 0.3

_E_COLS = ("e2_pulses", "e3_pulses")
_I_COLS = ("i2_A", "i3_A")


def _name(log) -> str:
    path = getattr(log, "path", None)
    return str(path.name if path is not None and hasattr(path, "name") else log.name)


def check_experiment(log, *, n_parameters: int, p_control: bool = True) -> None:
    """Refuse a log whose signals cannot carry an identification (module docstring).

    Parameters
    ----------
    log : plant.ExperimentLog
        The experiment (``e_pulses`` (n, 2), ``i_A`` (n, 2), ``q_ref`` (n, 2)).
    n_parameters : int
        Parameters the identification searches.
    p_control : bool
        The log was made by the rig's P law (check ``i = P e``); False for a
        log made by another controller (a CTC window).

    Raises
    ------
    plant.LogError
        One line naming the log, the column and the sample at fault.
    """
    name = _name(log)
    n = int(log.n_samples)
    need = max(MIN_SAMPLES, SAMPLES_PER_PARAMETER * int(n_parameters))
    if n < need:
        raise LogError(f"{name}: {n} samples are too few to identify {n_parameters} parameters "
                       f"(need at least {need})")
    e = np.asarray(log.e_pulses, dtype=float)
    i = np.asarray(log.i_A, dtype=float)
    if not np.any(e) and not np.any(i):
        raise LogError(f"{name}: every tracking error and current is zero: nothing to identify "
                       "(was the robot moving?)")
    rig = log.rig
    ts = float(rig.sample_time_s)
    ppr = np.abs(np.asarray(rig.pulses_per_rad, dtype=float))
    q_ref = np.asarray(log.q_ref, dtype=float)
    start = int(getattr(log, "start_index", 0) or 0)
    for j in range(2):
        limit = (float(np.max(np.abs(q_ref[:, j]))) + 2.0 * math.pi) * ppr[j]
        bad = np.flatnonzero(np.abs(e[:, j]) > limit)
        if bad.size:
            k = int(bad[0])
            raise LogError(f"{name}: {_E_COLS[j]} = {e[k, j]:.0f} pulses at sample {start + k} is "
                           f"more than a joint turn past the reference ({limit:.0f} pulses): "
                           "not an encoder count")
    if n > 1:
        qd_ref = np.abs(np.diff(q_ref, axis=0)) / ts
        for j in range(2):
            step = (float(qd_ref[:, j].max()) + MAX_JOINT_SPEED) * ts * ppr[j] + 2.0
            bad = np.flatnonzero(np.abs(np.diff(e[:, j])) > step)
            if bad.size:
                k = int(bad[0]) + 1
                raise LogError(f"{name}: {_E_COLS[j]} jumps by {e[k, j] - e[k - 1, j]:.0f} pulses "
                               f"at sample {start + k} (at most {step:.0f} in one sample at "
                               f"{MAX_JOINT_SPEED:g} rad/s): not an encoder count")
    fs = getattr(rig, "current_full_scale_A", None)
    i_max = CURRENT_FACTOR * float(fs) if fs else MAX_CURRENT_A
    for j in range(2):
        bad = np.flatnonzero(np.abs(i[:, j]) > i_max)
        if bad.size:
            k = int(bad[0])
            what = f"{CURRENT_FACTOR:g} x the drive's full scale ({fs:g} A)" if fs else f"{i_max:g} A"
            raise LogError(f"{name}: {_I_COLS[j]} = {i[k, j]:.4g} A at sample {start + k} is beyond "
                           f"{what}: not a drive current")
    if p_control:
        p = np.asarray(rig.p_gain_A_per_pulse, dtype=float)
        pred = e * p
        if fs:
            pred = np.clip(pred, -float(fs), float(fs))
        for j in range(2):
            if not np.any(i[:, j]):
                continue  # currents not logged on this joint
            # samples the drive may have clipped at a limit the sidecar does not state
            # (|P e| beyond the largest logged current) say nothing about the law
            keep = np.abs(pred[:, j]) <= np.max(np.abs(i[:, j])) + P_LAW_NOISE_A
            if np.count_nonzero(keep) < max(MIN_SAMPLES // 2, 1):
                continue
            d = i[keep, j] - pred[keep, j]
            mismatch = float(np.sqrt(np.mean(d * d)))
            scale = float(np.sqrt(np.mean(pred[keep, j] ** 2)))
            if mismatch > P_LAW_RELATIVE * scale + P_LAW_NOISE_A:
                raise LogError(
                    f"{name}: {_I_COLS[j]} disagrees with the rig's P law i = P e "
                    f"({_E_COLS[j]}, P = {p[j]:g} A/pulse): RMS mismatch {mismatch:.3g} A against "
                    f"RMS P e {scale:.3g} A -- error columns swapped, wrong p_gain in the "
                    "sidecar, or not a P-control log")
