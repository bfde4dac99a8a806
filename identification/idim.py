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
   the motion, :func:`plant.robot.model.friction_torque`), filtered by the *same*
   low-pass (parallel filtering: both sides of ``Y f = tau`` see the same
   filter);
4. the equations of a joint near its velocity reversals are dropped
   (below);
5. optional decimation, then ordinary least squares ``Y(q, qd, qdd) f = tau``
   with :func:`plant.robot.model.regressor`, the ends (filter transients) dropped.

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

Unknown friction
----------------
A sidecar with ``"viscous_friction_Nms_per_rad": null`` and/or
``"coulomb_friction_Nm": null`` (:attr:`plant.logs.rig.Rig.unknown_friction`)
does not know the drive friction, and ``k Kt i`` alone is not the joint
torque.  As in the classical IDIM (M. Gautier and W. Khalil, "Exciting
trajectories for the identification of base inertial parameters of robots",
Int. J. Robotics Research 11, 1992; J. Swevers et al., "Optimal robot
excitation and identification", IEEE Trans. Robot. Autom. 13, 1997) the unknown components
are identified with f as columns of the regressor
(:func:`friction_columns`): the joint equation is
``Y f + k^2 B qd + abs(k) Tc r(qd) = k Kt i`` with the library's friction
parameterisation (:data:`plant.simulation.friction.FRICTION_NAMES`: motor-side ``B2,
B3, Tc2+, Tc2-, Tc3+, Tc3-``; ``Tc+`` acts for a positive joint rate,
``Tc-`` otherwise) and the rig's linear Coulomb ramp ``r`` below its
``coulomb_ramp_speed`` (motor side), evaluated at the filtered rate and
filtered by the same low-pass as the torque.  Only the unknown components
get columns; the known ones stay subtracted as above.  The reversal guard
keeps the equations where the filtered rate's sign, hence the Coulomb
column, is reliable.

With unknown Coulomb friction the joint-2 equation carries a constant
offset ``abs(k2) (Tc2+ - Tc2-) / 2`` that a trajectory over a quarter turn
of q2 hardly tells from the gravity columns f8, f9 (correlation 0.99 on the
paper log), and through them from f2.  The equations are then weighted as in
Gautier's IDIM-WLS (Gautier and Poignet 2001): each joint's by the inverse
of the rms of its OLS residual (the joint-3 equation, free of that offset,
is about three times more precise), which on the paper log with all the
friction unknown cuts the error of f2 from 7.5 % to 2.6 % (IV: 6.7 % to
1.4 %) and of Tc2+ from 16 % to 6.5 %.  A rig whose friction is known keeps
the ordinary least squares above unchanged.  IDIM-IV simulates the closed
loop with the current friction estimate (negative components clipped at
zero) and takes the friction columns of the simulated rates as their
instruments.

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
from plant.robot.model import friction_torque, regressor
from plant.logs.rig import rig_constants

from .uncertainty import RSE_WARN, poorly_excited, sandwich_covariance, structure_scale

__all__ = ["idim_ls", "idim_cutoff_hz", "cutoff_from_counts", "identify_idim", "FLOOR_MARGIN_DB",
           "REVERSAL_GUARD", "IV_ITERATIONS", "reversal_mask", "friction_columns"]

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
    return cutoff_from_counts(plant.measured_counts(log), log.rig.sample_time_s)


def cutoff_from_counts(counts, ts):
    """:func:`idim_cutoff_hz` from the encoder counts of any number of joints.

    Parameters
    ----------
    counts : ndarray, shape (n_samples, n_joints)
        Measured encoder counts.
    ts : float
        Sample time (s).

    Returns
    -------
    float
        The low-pass cut-off (Hz): the lowest joint's frequency where the
        counts' spectrum meets the quantisation floor, within
        ``[2, fs / 20]`` Hz.
    """
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


def friction_columns(qd, c, k, unknown):
    """Regressor columns of the unknown motor-side friction, shape (n_samples, 2, n_unknown).

    The joint equation is ``Y f + k^2 B qd + abs(k) Tc r(qd) = k Kt i`` (the
    friction opposes the motion, :func:`plant.robot.model.friction_torque`), with
    ``r(qd) = clip(qd / v_ramp_joint, -1, 1)`` the rig's linear Coulomb ramp
    and ``Tc`` the level for the sign of ``qd`` (positive rate: ``Tc+``,
    otherwise ``Tc-``).  The unknowns are motor side, the sidecar's units and
    :data:`plant.simulation.friction.FRICTION_NAMES` order (``B2, B3, Tc2+, Tc2-, Tc3+,
    Tc3-``), so the columns are ``k_j^2 qd_j`` and ``abs(k_j) r(qd_j) [qd_j > 0]``,
    ``abs(k_j) r(qd_j) [qd_j <= 0]`` in the equations of joint j, zero in the
    other joint's.

    Parameters
    ----------
    qd : ndarray, shape (n_samples, 2)
        Filtered joint rates (rad/s).
    c : plant.logs.rig.RigConstants
        For the joint-side ramp speed ``v_ramp / abs(k)`` (rad/s).
    k : array_like, shape (2,)
        Gear ratios (motor angle = k joint angle).
    unknown : sequence of int
        Indices into ``FRICTION_NAMES`` of the columns wanted
        (:func:`identification.friction.unknown_friction_indices`).

    Returns
    -------
    ndarray, shape (n_samples, 2, len(unknown))
        Columns in N m per unit of the motor-side friction (N m s/rad for B,
        dimensionless for Tc).
    """
    qd = np.asarray(qd, dtype=float)
    k = np.asarray(k, dtype=float)
    r = np.clip(qd / np.asarray(c.ramp_speed), -1.0, 1.0)
    pos = qd > 0.0
    full = np.zeros(qd.shape[:1] + (2, 6))
    for j in range(2):
        full[:, j, j] = k[j] * k[j] * qd[:, j]
        full[:, j, 2 + 2 * j] = abs(k[j]) * r[:, j] * pos[:, j]
        full[:, j, 3 + 2 * j] = abs(k[j]) * r[:, j] * ~pos[:, j]
    return full[:, :, list(unknown)]


def idim_ls(log, *, cutoff_hz=None, decimate=1, trim_s=0.1, iv_iterations=0,
            reversal_guard=REVERSAL_GUARD):
    """Identify f1..f9 by IDIM-LS (inverse dynamic model, ordinary least squares).

    When the rig does not know its drive friction (:attr:`plant.logs.rig.Rig.unknown_friction`),
    the unknown motor-side components are identified with f: the regressor
    gets their columns (:func:`friction_columns`, evaluated at the filtered
    rates and filtered like the torque), the known ones stay subtracted
    (module docstring, "Unknown friction").

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
        already applied to ``f_cov`` and ``x_cov``); the estimated vector
        ``x`` (9 + u,) = f then the u unknown friction components (motor
        side, :data:`plant.simulation.friction.FRICTION_NAMES` order; u = 0 when the
        rig knows its friction), ``x_names``, ``x_std`` (9 + u,), ``x_cov``
        (9 + u, 9 + u), ``friction_unknown`` (their indices into
        ``FRICTION_NAMES``) and ``friction`` (6,), the full motor-side
        friction vector (known components from the rig, unknown ones
        identified).

    Raises
    ------
    ValueError
        On a bad cut-off, decimation or guard, a log too short for the
        filter, or unknown friction the log cannot identify (a joint that
        never moves in one direction among the equations kept).
    """
    from plant.simulation.friction import FRICTION_NAMES, friction_vector
    from plant.logs.rig import F_NAMES

    from .friction import unknown_friction_indices

    rig = log.rig
    ts = rig.sample_time_s
    counts = plant.measured_counts(log)
    fc = cutoff_from_counts(counts, ts) if cutoff_hz is None else float(cutoff_hz)
    if not (0 < fc < 0.5 / ts):
        raise ValueError(f"cutoff_hz must lie in (0, {0.5 / ts:.4g}) Hz, got {cutoff_hz}")
    decimate = int(decimate)
    if decimate < 1:
        raise ValueError(f"decimate must be >= 1, got {decimate}")
    if reversal_guard is not None and not (np.isfinite(reversal_guard) and reversal_guard >= 0):
        raise ValueError(f"reversal_guard must be >= 0 or None, got {reversal_guard!r}")
    c = rig_constants(rig)  # unknown friction is zero here: only the known part is subtracted
    unknown = unknown_friction_indices(rig)
    nu = len(unknown)
    gear = np.asarray(rig.gear_ratio, dtype=float)
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
    if nu:  # unknown friction: its columns, filtered like the torque (parallel filtering)
        Phi = signal.sosfiltfilt(sos, friction_columns(qd, c, gear, unknown), axis=0)
        W = np.hstack([W, Phi[sl].reshape(-1, nu) * weight])
        empty = [FRICTION_NAMES[u] for u, col in zip(unknown, W[:, 9:].T)
                 if not np.any(col != 0)]
        if empty:
            raise ValueError(f"the log cannot identify the unknown friction {', '.join(empty)}: "
                             "its joint does not move in that direction in the equations kept")
    y = tauf[sl].reshape(-1) * weight[:, 0]
    scale = np.linalg.norm(W, axis=0)
    scale[scale == 0] = 1.0
    fs_, *_ = np.linalg.lstsq(W / scale, y, rcond=None)
    x = fs_ / scale
    row_w = None
    if nu:  # weighted least squares, each joint by 1 / its OLS residual rms (module docstring)
        r0 = (W @ x - y).reshape(-1, 2)
        kept = weight.reshape(-1, 2) > 0
        sigma = np.array([np.sqrt(np.mean(r0[kept[:, j], j] ** 2)) if kept[:, j].any() else 0.0
                          for j in range(2)])
        if np.all(sigma > 0):
            row_w = np.tile(1.0 / sigma, W.shape[0] // 2)
            W = W * row_w[:, None]
            y = y * row_w
            weight = weight * row_w[:, None]
            fs_, *_ = np.linalg.lstsq(W / scale, y, rcond=None)
            x = fs_ / scale
    done = 0
    for _ in range(int(iv_iterations)):
        Zk = _instruments(log, x, sos, sl, c, unknown)
        if Zk is None:
            break
        Z = Zk * weight
        x = np.linalg.solve(Z.T @ W, Z.T @ y)
        done += 1
    r = W @ x - y
    if done:
        A = np.linalg.inv(Z.T @ W)
        # the IV sandwich: (Z^T W)^-1 S (W^T Z)^-1 with S of the scores Z_t r_t;
        # sandwich_covariance(Z, r) returns (Z^T Z)^-1 S (Z^T Z)^-1
        cz, info = sandwich_covariance(Z, r, n_channels=2)
        ZZ = Z.T @ Z
        cov = A @ ZZ @ cz @ ZZ @ A.T
    else:
        cov, info = sandwich_covariance(W, r, n_channels=2)
    f = x[:9]
    # model adequacy: eq. 3's identities f3 = a3 f5, f4 = a3 f6 (the estimate
    # does not enforce them); violated beyond the statistical error, the
    # covariance is inflated (the output-error method's rule)
    inflate, wald = structure_scale(f, cov[:9, :9], rig.a3_m)
    cov = cov * inflate * inflate
    x_std = np.sqrt(np.maximum(np.diag(cov), 0))
    f_std = x_std[:9]
    sv = np.linalg.svd(W / scale, compute_uv=False)
    n_eq = int(np.count_nonzero(weight))
    if row_w is not None:  # the residual in N m, not in units of the joint weights
        r = r / row_w
    friction = friction_vector(rig)
    friction[unknown] = x[9:]
    return dict(f=f, f_std=f_std, f_cov=cov[:9, :9], f_rse=f_std / np.abs(f), cutoff_hz=fc,
                n_equations=n_eq, residual_rms_Nm=float(np.sqrt(np.sum(r * r) / max(n_eq, 1))),
                condition_number=float(sv[0] / sv[-1]), lag=info["lag"], iv_iterations=done,
                n_dropped=int(weight.size - n_eq), scale=inflate, wald=wald,
                x=x, x_names=list(F_NAMES) + [FRICTION_NAMES[u] for u in unknown],
                x_std=x_std, x_cov=cov, friction_unknown=list(unknown), friction=friction)


def _instruments(log, x, sos, sl, c, unknown=()):
    """Regressor of the simulated P loop at x (IDIM-IV instruments), or None if it fails.

    Parameters
    ----------
    log : plant.ExperimentLog
    x : ndarray, shape (9 + len(unknown),)
        Current estimate: f1..f9, then the unknown motor-side friction.
    sos : ndarray
        The IDIM low-pass (second-order sections).
    sl : slice
        The equations' samples.
    c : plant.logs.rig.RigConstants
        The log's rig constants (unknown friction zero).
    unknown : sequence of int
        Indices into :data:`plant.simulation.friction.FRICTION_NAMES` of the unknown friction.

    Returns
    -------
    ndarray, shape (2 n_eq, 9 + len(unknown)) or None
        ``Y`` and the friction columns (:func:`friction_columns`) of the
        simulated, noise-free positions through the same filter and
        differences.  With unknown friction the simulated robot has the
        current estimate of it (the rig's known friction, the unknown
        components from x, clipped at 0: a negative friction is no robot).
    """
    from plant.simulation.synthetic import EMULATION_SUBSTEPS, CardPLaw

    rig = log.rig
    ts = rig.sample_time_s
    f = np.asarray(x[:9], dtype=float)
    source = log
    if len(unknown):
        from dataclasses import replace

        from plant.simulation.friction import friction_vector

        v = friction_vector(rig)
        v[list(unknown)] = np.maximum(np.asarray(x[9:], dtype=float), 0.0)
        # the rigid plant reads the friction from the rig (plant.logs.rig.rig_constants)
        source = replace(rig, viscous_friction_Nms_per_rad=(float(v[0]), float(v[1])),
                         coulomb_friction_Nm=((float(v[2]), float(v[3])),
                                              (float(v[4]), float(v[5]))))
    try:
        resp = plant.simulate_closed_loop(source, f, CardPLaw(rig.p_gain_A_per_pulse),
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
    Z = regressor(qs[sl], qds[sl], qdds[sl], c.gravity).reshape(-1, 9)
    if len(unknown):
        Phi = signal.sosfiltfilt(sos, friction_columns(qds, c, rig.gear_ratio, unknown), axis=0)
        Z = np.hstack([Z, Phi[sl].reshape(-1, len(unknown))])
    return Z


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
        error of eq. 4 at f, simulated with the identified friction when the
        rig's is unknown) and the model keys of
        :data:`identification.models.MODEL_KEYS`.  A rig with unknown
        friction (:attr:`plant.logs.rig.Rig.unknown_friction`) gives, as
        :func:`identification.identify`'s output-error methods do, ``x`` =
        f then the identified friction components (``x_names``, motor side),
        their standard errors ``x_std`` and correlations ``x_correlation``,
        ``parameters`` ``'base+friction'``, ``viscous_friction_Nms_per_rad``
        and ``coulomb_friction_Nm`` identified (the known components the
        sidecar's) and ``friction_identified`` True; otherwise the sidecar's
        friction echoed and ``friction_identified`` False.
    """
    import warnings

    from .friction import FrictionParameters
    from .models import result_entries
    from .objective import OutputError
    from .parameters import BaseParameters
    from .result import IdentificationResult
    from .uncertainty import PoorExcitationWarning, correlation_matrix, warning_text

    compile_s = plant.warm_up(closed_loop=False)
    t0 = time.perf_counter()
    iv = IV_ITERATIONS if method == "idim-iv" else 0
    res = idim_ls(log, iv_iterations=iv)
    f = res["f"]
    x = res["x"]
    space = BaseParameters()
    if res["friction_unknown"]:  # the GA path's parameterisation: same result keys
        space = FrictionParameters(space)
    objective = OutputError(log, substeps=substeps, lowpass_hz=lowpass_hz, workers=workers,
                            plant=space.plant(log))
    extra = space.plant_parameters(x[None], log)
    if extra is None:  # the rigid plant's call (the rig knows its friction)
        fun = float(objective(f[None])[0])
    else:
        fun = float(objective(f[None], plant_parameters=extra)[0])
    bad = poorly_excited(res["f_rse"])
    if bad:
        warnings.warn(warning_text(bad, res["f_rse"]), PoorExcitationWarning, stacklevel=3)
    wall = time.perf_counter() - t0
    n_fr = len(res["friction_unknown"])
    unc = dict(method=("IV" if iv else "OLS") + " sandwich, Newey-West (Bartlett) HAC",
               lag=res["lag"], scale=res["scale"], wald=res["wald"], rse_threshold=RSE_WARN)
    extras = {}
    if n_fr:
        unc["method"] = ("IV" if iv else "WLS") + " sandwich, Newey-West (Bartlett) HAC"
        unc["x_names"] = list(res["x_names"])
        extras["x_correlation"] = correlation_matrix(res["x_cov"])
    return IdentificationResult(
        x=x.copy(), f=f, fun=fun, nfev=1, nit=1, success=True,
        message=f"{method.upper()}: {res['n_equations']} equations, low-pass "
                f"{res['cutoff_hz']:.3g} Hz" + (f", {res['iv_iterations']} IV iterations"
                                                 if iv else "")
                + (f", {n_fr} friction components identified" if n_fr else ""),
        population=None, population_energies=None, method=method, seed=seed,
        history={"generation": np.arange(1), "best": np.array([fun]), "mean": np.array([fun]),
                 "nfev": np.array([1])},
        refinement=None, wall_time_s=wall, compile_time_s=compile_s, interrupted=False,
        log_name=log.name, log=log, bounds=space.bounds(log), x_names=list(res["x_names"]),
        parameters=space.name,
        settings=dict(substeps=int(substeps), lowpass_hz=lowpass_hz,
                      idim=dict(cutoff_hz=res["cutoff_hz"], filter_order=IDIM_FILTER_ORDER,
                                iv_iterations=iv)),
        f_std=res["f_std"], f_rse=res["f_rse"], f_correlation=correlation_matrix(res["f_cov"]),
        x_std=res["x_std"], poorly_excited=bad, uncertainty=unc,
        idim=dict(cutoff_hz=res["cutoff_hz"], n_equations=res["n_equations"],
                  n_dropped=res["n_dropped"], residual_rms_Nm=res["residual_rms_Nm"],
                  condition_number=res["condition_number"]),
        **extras, **result_entries(space, x, log),
    )
