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
4. the equations of a joint near its velocity reversals are dropped
   (below);
5. optional decimation, then ordinary least squares ``Y(q, qd, qdd) f = tau``
   with :func:`plant.model.regressor`, the ends (filter transients) dropped.

Cut-off rule
------------
The positions come from an encoder: their error is the quantisation error,
uniform over one count, a white floor of ``1/12`` pulse^2 spread over the
Nyquist band when the motor moves (Widrow and Kollar, *Quantization Noise*,
2008).  Double differentiation amplifies it as ``omega^4``, and least
squares with a noisy regressor is biased (errors in variables).  The motion
itself is the reference's band *and* the P loop's own, lightly damped mode
(~13 Hz on the PUMA rigs), which carries most of what identifies the
inertias.  The rule measures the bandwidth of the joint motion against the
known floor: ``f_c`` is the highest frequency at which the Welch spectrum of
the encoder counts stands :data:`FLOOR_MARGIN_DB` (20 dB) above the
quantisation floor, the lower of the two joints', clipped to
``[2 Hz, f_s / 20]``.  It depends on the sample rate, the encoder and the
motion, not on a parameter of one log.  A ``cutoff_hz`` overrides it.  The previous
rule, ``max(10 f_ref, 3 f_loop)``, put the cut-off in the floor (40 Hz on
the PUMA rigs); with it, and no reversal guard, IDIM-LS missed the paper
log's f2 by 5.3 %.  Measured by ``benchmarks/bench_methods.py`` and
``tests/test_uncertainty.py`` on the rigid logs (table in the methods
comparison page); on flexible joints the rigid model is wrong in the very
band that identifies the inertias, whatever the cut-off.

Velocity reversals
------------------
Near a reversal the Coulomb friction's sign is not known: under P control
the joint sticks and slips at the encoder's resolution, and the filtered
rate passes smoothly through zero while the true one chatters.  The known
friction evaluated at the filtered rate is then wrong by up to twice the
Coulomb level, and the filter spreads that error over about ``1 / f_c``.
As in Gautier's practice of discarding low-velocity samples, the equations
of joint j within :data:`REVERSAL_GUARD` ``/ f_c`` of a sign change of its
filtered rate are dropped (weighted zero, so the Newey-West estimator keeps
its time order).

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
regressor as the Jacobian and the equation errors as residuals), inflated
like it when eq. 3's identities are violated beyond their statistical
error (:func:`identification.uncertainty.structure_scale`: the rigid model
does not describe the log, e.g. flexible joints).
"""
from __future__ import annotations

import time

import numpy as np
from scipy import signal

import plant
from plant.model import friction_torque, regressor
from plant.rig import rig_constants

from .uncertainty import RSE_WARN, poorly_excited, sandwich_covariance, structure_scale

__all__ = ["idim_ls", "idim_cutoff_hz", "identify_idim", "FLOOR_MARGIN_DB", "REVERSAL_GUARD",
           "IV_ITERATIONS", "reversal_mask"]

#: Instrumental-variable iterations of IDIM-IV.
IV_ITERATIONS = 3

#: The IDIM cut-off is the highest frequency at which the counts' spectrum stands
#: this far (dB) above the encoder's quantisation floor.
FLOOR_MARGIN_DB = 20.0
#: Equations of a joint within ``REVERSAL_GUARD / f_c`` (s) of a reversal of its
#: filtered rate are dropped (Coulomb friction's sign unknown there).
REVERSAL_GUARD = 1.0
#: Butterworth order of the IDIM filter (applied forward and backward).
IDIM_FILTER_ORDER = 4


def idim_cutoff_hz(log) -> float:
    """The documented cut-off rule: where the motion meets the quantisation floor.

    Parameters
    ----------
    log : plant.ExperimentLog

    Returns
    -------
    float
        Cut-off (Hz): the highest frequency at which the Welch spectrum of the
        encoder counts (:func:`plant.measured_counts`, linear trend removed)
        stands :data:`FLOOR_MARGIN_DB` above the quantisation floor
        ``(1/12) / (f_s / 2)`` pulse^2/Hz, the lower of the two joints',
        clipped to ``[2 Hz, f_s / 20]`` (module docstring, "Cut-off rule").
    """
    return _floor_cutoff_hz(plant.measured_counts(log), log.rig.sample_time_s)


def _floor_cutoff_hz(counts, ts):
    """:func:`idim_cutoff_hz` from the counts (n, 2) and the sample time (s)."""
    fs = 1.0 / ts
    nperseg = int(min(1024, max(64, counts.shape[0] // 4)))
    freq, psd = signal.welch(counts, fs=fs, axis=0, nperseg=min(nperseg, counts.shape[0]),
                             detrend="linear")
    level = (1.0 / 12.0) / (0.5 * fs) * 10.0 ** (FLOOR_MARGIN_DB / 10.0)
    edges = []
    for j in range(psd.shape[1]):
        above = np.flatnonzero(psd[:, j] > level)
        edges.append(float(freq[above[-1]]) if above.size else 0.0)
    return float(np.clip(min(edges), 2.0, fs / 20.0))


def reversal_mask(qd, guard_samples):
    """Equations kept by the reversal guard, shape (n_samples, 2) bool.

    Parameters
    ----------
    qd : ndarray, shape (n_samples, 2)
        Filtered joint rates (rad/s).
    guard_samples : int
        Half-width of the dropped window around each sign change (samples).

    Returns
    -------
    ndarray of bool, shape (n_samples, 2)
        False within ``guard_samples`` of a sign change of ``qd[:, j]``.
    """
    from scipy.ndimage import binary_dilation

    qd = np.asarray(qd, dtype=float)
    flip = np.zeros(qd.shape, dtype=bool)
    flip[1:] = np.sign(qd[1:]) != np.sign(qd[:-1])
    g = int(guard_samples)
    if g > 0:
        flip = binary_dilation(flip, structure=np.ones((2 * g + 1, 1), dtype=bool))
    return ~flip


def _friction(qd, c):
    out = np.empty_like(qd)
    for j in range(2):
        for i in range(qd.shape[0]):
            out[i, j] = friction_torque(qd[i, j], c.viscous[j], c.coulomb_pos[j],
                                        c.coulomb_neg[j], c.ramp_speed[j])
    return out


def idim_ls(log, *, cutoff_hz=None, decimate=1, trim_s=0.1, iv_iterations=0,
            reversal_guard=REVERSAL_GUARD):
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
    reversal_guard : float or None
        Equations of a joint within ``reversal_guard / f_c`` seconds of a sign
        change of its filtered rate are dropped (module docstring); 0 drops
        only the samples of the sign changes, ``None`` keeps all.

    Returns
    -------
    dict
        ``f`` (9,), ``f_std`` (9,), ``f_cov`` (9, 9), ``f_rse`` (9,),
        ``cutoff_hz``, ``n_equations``, ``residual_rms_Nm``,
        ``condition_number`` (of the column-scaled regressor), ``lag``
        (Newey-West lag), ``iv_iterations`` (IV iterations that ran),
        ``n_dropped`` (equations dropped by the reversal guard), ``scale``
        and ``wald`` (:func:`identification.uncertainty.structure_scale`,
        already applied to ``f_cov``).

    Raises
    ------
    ValueError
        On a bad cut-off, decimation or guard, or a log too short for the filter.
    """
    rig = log.rig
    ts = rig.sample_time_s
    counts = plant.measured_counts(log)
    fc = _floor_cutoff_hz(counts, ts) if cutoff_hz is None else float(cutoff_hz)
    if not (0 < fc < 0.5 / ts):
        raise ValueError(f"cutoff_hz must lie in (0, {0.5 / ts:.4g}) Hz, got {cutoff_hz}")
    decimate = int(decimate)
    if decimate < 1:
        raise ValueError(f"decimate must be >= 1, got {decimate}")
    if reversal_guard is not None and not (np.isfinite(reversal_guard) and reversal_guard >= 0):
        raise ValueError(f"reversal_guard must be >= 0 or None, got {reversal_guard!r}")
    c = rig_constants(rig)
    sos = signal.butter(IDIM_FILTER_ORDER, fc, fs=1.0 / ts, output="sos")
    q = counts / np.asarray(c.pulses_per_rad)
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
    if reversal_guard is None:
        keep = np.ones((n, 2), dtype=bool)
    else:
        keep = reversal_mask(qd, round(reversal_guard / (fc * ts)))
    weight = keep[sl].reshape(-1, 1).astype(float)  # dropped equations weigh zero
    W = regressor(qf[sl], qd[sl], qdd[sl], c.gravity).reshape(-1, 9) * weight
    y = tauf[sl].reshape(-1) * weight[:, 0]
    scale = np.linalg.norm(W, axis=0)
    scale[scale == 0] = 1.0
    fs_, *_ = np.linalg.lstsq(W / scale, y, rcond=None)
    f = fs_ / scale
    done = 0
    for _ in range(int(iv_iterations)):
        Zk = _instruments(log, f, sos, sl, c)
        if Zk is None:
            break
        Z = Zk * weight
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
    # model adequacy: eq. 3's identities f3 = a3 f5, f4 = a3 f6 (the estimate
    # does not enforce them); violated beyond the statistical error, the
    # covariance is inflated (the output-error method's rule)
    inflate, wald = structure_scale(f, cov, rig.a3_m)
    cov = cov * inflate * inflate
    f_std = np.sqrt(np.maximum(np.diag(cov), 0))
    sv = np.linalg.svd(W / scale, compute_uv=False)
    n_eq = int(np.count_nonzero(weight))
    return dict(f=f, f_std=f_std, f_cov=cov, f_rse=f_std / np.abs(f), cutoff_hz=fc,
                n_equations=n_eq, residual_rms_Nm=float(np.sqrt(np.sum(r * r) / max(n_eq, 1))),
                condition_number=float(sv[0] / sv[-1]), lag=info["lag"], iv_iterations=done,
                n_dropped=int(weight.size - n_eq), scale=inflate, wald=wald)


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
        ``poorly_excited``, ``idim`` (cut-off, equations kept and dropped by
        the reversal guard, residual, condition number), ``fun`` (output
        error of eq. 4 at f).
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
        uncertainty=dict(method=("IV" if iv else "OLS") + " sandwich, Newey-West (Bartlett) HAC",
                         lag=res["lag"], scale=res["scale"], wald=res["wald"],
                         rse_threshold=RSE_WARN),
        idim=dict(cutoff_hz=res["cutoff_hz"], n_equations=res["n_equations"],
                  n_dropped=res["n_dropped"], residual_rms_Nm=res["residual_rms_Nm"],
                  condition_number=res["condition_number"]),
    )
