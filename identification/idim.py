"""IDIM-LS: the classical inverse-dynamic identification model by least squares.

The standard method of industrial-robot identification (M. Gautier,
"Dynamic identification of robots with power model", ICRA 1997; Gautier and
Poignet, "Extended Kalman filtering and weighted least squares dynamic
identification of robot", Control Eng. Practice 9, 2001), side by side with
the paper's closed-loop output-error GA:

1. positions from the encoder counts, at the centres of the count intervals
   the log allows (:func:`plant.measured_counts`);
2. a zero-phase Butterworth low-pass (order 4, ``scipy.signal.sosfiltfilt``)
   of the positions, then central differences for qd and qdd;
3. the joint torque ``k Kt i`` from the logged currents (the current held
   over sample k acts around ``t_k + Ts/2``: averaged over samples k-1, k),
   plus the known joint-side drive friction at the filtered rates (it opposes
   the motion, :func:`plant.model.friction_torque`), filtered by the *same*
   low-pass (parallel filtering: both sides of ``Y f = tau`` see the same
   filter);
4. optional decimation, then ordinary least squares ``Y(q, qd, qdd) f = tau``
   with :func:`plant.model.regressor`, the ends (filter transients) dropped.

Cut-off rule
------------
The motion lives in the reference's band (its highest harmonic ``f_ref``,
and the quintic ramp's ``~2 / t_ramp``); the filter must pass it
undistorted and cut the quantisation noise that double differentiation
amplifies as ``omega^2``.  The motion also rings at the P loop's own,
lightly damped mode (~10 Hz on the PUMA rigs), which the reference does not
show: cutting it distorts qdd and biased f7 by -80 % on the paper log at
5.5 Hz.  The rule is ``f_c = max(10 f_ref, 3 f_loop)`` (Gautier's "5 to 10
times the bandwidth of the joint motion"), ``f_loop`` the P loop's natural
frequency ``sqrt(P |k N / 2 pi| k Kt / J) / 2 pi`` with J the middle of the
sidecar's prior range of the diagonal inertia (f7, f1), clipped to
``[2 Hz, f_s / 20]``.  (A peak search in the currents' spectrum was tried
and was not robust.)  A ``cutoff_hz`` overrides it.

IDIM-IV
-------
Least squares is biased when the regressor is noisy: the filtered,
twice-differentiated quantised positions carry errors correlated with the
equation error (the P loop feeds the same quantisation into the current).
The instrumental-variable estimate (M. Gautier, A. Janot, P.-O. Vandanjon,
"A new closed-loop output error method for parameter identification of
robot dynamics", IEEE Trans. Control Syst. Technol. 21, 2013; A. Janot,
P.-O. Vandanjon, M. Gautier, "A generic instrumental variable approach for
industrial robot identification", IEEE TCST 22, 2014) uses as instruments
the regressor ``Z`` of the *simulated* closed loop (the rig's P loop, the
current estimate, the same reference; noise-free positions through the same
filter and differences): ``f = (Z^T W)^-1 Z^T tau``, started from IDIM-LS
and iterated ``IV_ITERATIONS`` times (the estimate settles after two; a
failed simulation keeps the previous estimate).  Standard errors: the IV
sandwich ``(Z^T W)^-1 S (W^T Z)^-1`` with the Newey-West S of the scores
``Z_t r_t``.

Standard errors are the same Newey-West sandwich as the output-error
method's (:func:`identification.uncertainty.sandwich_covariance`, with the
regressor as the Jacobian and the equation errors as residuals).
"""
from __future__ import annotations

import math
import time

import numpy as np
from scipy import signal

import plant
from plant.model import friction_torque, regressor
from plant.rig import rig_constants

from .uncertainty import RSE_WARN, poorly_excited, sandwich_covariance

__all__ = ["idim_ls", "idim_cutoff_hz", "identify_idim", "CUTOFF_FACTOR", "IV_ITERATIONS"]

#: Instrumental-variable iterations of IDIM-IV.
IV_ITERATIONS = 3

#: Cut-off of the IDIM low-pass as a multiple of the trajectory's highest frequency.
CUTOFF_FACTOR = 10.0
#: ... and as a multiple of the closed loop's mode frequency.
LOOP_FACTOR = 3.0
#: Butterworth order of the IDIM filter (applied forward and backward).
IDIM_FILTER_ORDER = 4


def idim_cutoff_hz(log) -> float:
    """The documented cut-off rule: ``10 f_ref`` clipped to ``[2 Hz, f_s / 20]``.

    Parameters
    ----------
    log : plant.ExperimentLog

    Returns
    -------
    float
        Cut-off (Hz).
    """
    traj = log.trajectory
    om = np.abs(np.asarray(traj.omega, dtype=float))
    amp = np.abs(np.asarray(traj.amplitude, dtype=float))
    f_ref = float(np.max(om[amp > 0], initial=0.0)) / (2 * math.pi)
    if traj.t_ramp_s > 0:
        f_ref = max(f_ref, 2.0 / traj.t_ramp_s)
    fs = 1.0 / log.rig.sample_time_s
    # the P loop's own mode, sqrt(P |k N / 2 pi| k Kt / J) with J the middle of
    # the sidecar's prior ranges of the diagonal inertias f7 (joint 2), f1 (joint 3)
    c = rig_constants(log.rig)
    J = log.rig.bounds[[6, 0]].mean(axis=1)
    w = np.sqrt(np.abs(np.asarray(c.p_gain) * np.asarray(c.pulses_per_rad)
                       * np.asarray(c.torque_per_amp)) / np.maximum(J, 1e-9))
    f_loop = float(np.max(w)) / (2 * math.pi)
    return float(np.clip(max(CUTOFF_FACTOR * f_ref, LOOP_FACTOR * f_loop), 2.0, fs / 20.0))


def _friction(qd, c):
    out = np.empty_like(qd)
    for j in range(2):
        for i in range(qd.shape[0]):
            out[i, j] = friction_torque(qd[i, j], c.viscous[j], c.coulomb_pos[j],
                                        c.coulomb_neg[j], c.ramp_speed[j])
    return out


def idim_ls(log, *, cutoff_hz=None, decimate=1, trim_s=0.1, iv_iterations=0):
    """Identify f1..f9 by IDIM-LS (inverse dynamic model, ordinary least squares).

    Parameters
    ----------
    log : plant.ExperimentLog
        A logged experiment (positions from the counts, torques from the
        logged currents).
    cutoff_hz : float, optional
        Low-pass cut-off (Hz); default :func:`idim_cutoff_hz`.
    decimate : int
        Keep every ``decimate``-th sample after filtering (1: all).
    trim_s : float
        Seconds dropped at both ends (filter transients).
    iv_iterations : int
        0: ordinary least squares (IDIM-LS); n > 0: IDIM-IV, n iterations of
        the instrumental-variable estimate with the simulated closed loop's
        regressor as instruments (module docstring).

    Returns
    -------
    dict
        ``f`` (9,), ``f_std`` (9,), ``f_cov`` (9, 9), ``f_rse`` (9,),
        ``cutoff_hz``, ``n_equations``, ``residual_rms_Nm``,
        ``condition_number`` (of the column-scaled regressor), ``lag``
        (Newey-West lag), ``iv_iterations`` (IV iterations that ran).

    Raises
    ------
    ValueError
        On a bad cut-off, decimation or a log too short for the filter.
    """
    rig = log.rig
    ts = rig.sample_time_s
    fc = idim_cutoff_hz(log) if cutoff_hz is None else float(cutoff_hz)
    if not (0 < fc < 0.5 / ts):
        raise ValueError(f"cutoff_hz must lie in (0, {0.5 / ts:.4g}) Hz, got {cutoff_hz}")
    decimate = int(decimate)
    if decimate < 1:
        raise ValueError(f"decimate must be >= 1, got {decimate}")
    c = rig_constants(rig)
    sos = signal.butter(IDIM_FILTER_ORDER, fc, fs=1.0 / ts, output="sos")
    q = plant.measured_counts(log) / np.asarray(c.pulses_per_rad)
    n = q.shape[0]
    n_trim = int(round(trim_s / ts))
    if n - 2 * n_trim < 50:
        raise ValueError(f"log too short for IDIM ({n} samples)")
    qf = signal.sosfiltfilt(sos, q, axis=0)
    qd = np.gradient(qf, ts, axis=0)
    qdd = np.gradient(qd, ts, axis=0)
    i = np.asarray(log.i_A, dtype=float)
    i_mid = np.vstack([i[:1], 0.5 * (i[1:] + i[:-1])])  # held current acts around t_k +- Ts/2
    tau = i_mid * np.asarray(c.torque_per_amp) + _friction(qd, c)  # friction_torque < 0 along qd
    tauf = signal.sosfiltfilt(sos, tau, axis=0)
    sl = slice(n_trim, n - n_trim, decimate)
    W = regressor(qf[sl], qd[sl], qdd[sl], c.gravity).reshape(-1, 9)
    y = tauf[sl].reshape(-1)
    scale = np.linalg.norm(W, axis=0)
    scale[scale == 0] = 1.0
    fs_, *_ = np.linalg.lstsq(W / scale, y, rcond=None)
    f = fs_ / scale
    done = 0
    for _ in range(int(iv_iterations)):
        Zk = _instruments(log, f, sos, sl, c)
        if Zk is None:
            break
        Z = Zk
        f = np.linalg.solve(Z.T @ W, Z.T @ y)
        done += 1
    r = W @ f - y
    if done:
        A = np.linalg.inv(Z.T @ W)
        # the IV sandwich: (Z^T W)^-1 S (W^T Z)^-1 with S of the scores Z_t r_t;
        # sandwich_covariance(Z, r) returns (Z^T Z)^-1 S (Z^T Z)^-1
        cz, info = sandwich_covariance(Z, r, n_channels=2)
        ZZ = Z.T @ Z
        cov = A @ ZZ @ cz @ ZZ @ A.T
    else:
        cov, info = sandwich_covariance(W, r, n_channels=2)
    f_std = np.sqrt(np.maximum(np.diag(cov), 0))
    sv = np.linalg.svd(W / scale, compute_uv=False)
    return dict(f=f, f_std=f_std, f_cov=cov, f_rse=f_std / np.abs(f), cutoff_hz=fc,
                n_equations=int(y.size), residual_rms_Nm=float(np.sqrt(np.mean(r * r))),
                condition_number=float(sv[0] / sv[-1]), lag=info["lag"], iv_iterations=done)


def _instruments(log, f, sos, sl, c):
    """Regressor of the simulated P loop at f (IDIM-IV instruments), or None if it fails."""
    from plant.synthetic import EMULATION_SUBSTEPS, _CardP

    rig = log.rig
    ts = rig.sample_time_s
    try:
        resp = plant.simulate_closed_loop(rig, f, _CardP(rig.p_gain_A_per_pulse),
                                          trajectory=log.trajectory, n_samples=log.n_total,
                                          substeps=EMULATION_SUBSTEPS // 8,
                                          label="IDIM-IV instruments")
    except ValueError:
        return None
    if not resp.success or resp.q.shape[0] < log.n_total:
        return None
    qs = signal.sosfiltfilt(sos, resp.q[log.start_index:], axis=0)
    qds = np.gradient(qs, ts, axis=0)
    qdds = np.gradient(qds, ts, axis=0)
    return regressor(qs[sl], qds[sl], qdds[sl], c.gravity).reshape(-1, 9)


def identify_idim(log, *, substeps, workers=None, lowpass_hz=None, seed=None,
                  method="idim-ls"):
    """``identify(log, method='idim-ls' | 'idim-iv')``: IDIM as an IdentificationResult.

    Parameters
    ----------
    log : plant.ExperimentLog
    substeps : int
        RK4 substeps of the output error ``fun`` evaluated at the result.
    workers : int, optional
        Threads of that simulation.
    lowpass_hz : float, optional
        Low-pass of the output error (as :func:`identification.identify`);
        the IDIM filter itself follows :func:`idim_cutoff_hz`.
    seed : int, optional
        Recorded only (the method is deterministic).
    method : {'idim-ls', 'idim-iv'}
        Least squares, or instrumental variables (:data:`IV_ITERATIONS`).

    Returns
    -------
    IdentificationResult
        ``method``, ``f``, ``f_std``, ``f_rse``, ``f_correlation``,
        ``poorly_excited``, ``idim`` (cut-off, equations, residual, condition
        number), ``fun`` (output error of eq. 4 at f).
    """
    import warnings

    from plant.rig import F_NAMES

    from .objective import OutputError
    from .result import IdentificationResult
    from .uncertainty import PoorExcitationWarning, _correlation, warning_text

    compile_s = plant.warm_up(closed_loop=False)
    t0 = time.perf_counter()
    iv = IV_ITERATIONS if method == "idim-iv" else 0
    res = idim_ls(log, iv_iterations=iv)
    f = res["f"]
    fun = float(OutputError(log, substeps=substeps, lowpass_hz=lowpass_hz,
                            workers=workers)(f[None])[0])
    bad = poorly_excited(res["f_rse"])
    if bad:
        warnings.warn(warning_text(bad, res["f_rse"]), PoorExcitationWarning, stacklevel=3)
    wall = time.perf_counter() - t0
    return IdentificationResult(
        x=f.copy(), f=f, fun=fun, nfev=1, nit=1, success=True,
        message=f"{method.upper()}: {res['n_equations']} equations, low-pass "
                f"{res['cutoff_hz']:.3g} Hz" + (f", {res['iv_iterations']} IV iterations"
                                                 if iv else ""),
        population=None, population_energies=None, method=method, seed=seed,
        history={"generation": np.arange(1), "best": np.array([fun]), "mean": np.array([fun]),
                 "nfev": np.array([1])},
        refinement=None, wall_time_s=wall, compile_time_s=compile_s, interrupted=False,
        log_name=log.name, log=log, bounds=log.rig.bounds, x_names=list(F_NAMES),
        parameters="base",
        settings=dict(substeps=int(substeps), lowpass_hz=lowpass_hz,
                      idim=dict(cutoff_hz=res["cutoff_hz"], filter_order=IDIM_FILTER_ORDER,
                                iv_iterations=iv)),
        f_std=res["f_std"], f_rse=res["f_rse"], f_correlation=_correlation(res["f_cov"]),
        x_std=res["f_std"], poorly_excited=bad,
        uncertainty=dict(method=("IV" if iv else "OLS") + " sandwich, Newey-West (Bartlett) HAC", lag=res["lag"],
                         rse_threshold=RSE_WARN),
        idim=dict(cutoff_hz=res["cutoff_hz"], n_equations=res["n_equations"],
                  residual_rms_Nm=res["residual_rms_Nm"],
                  condition_number=res["condition_number"]),
    )
