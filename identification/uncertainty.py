"""Standard errors of the identified parameters (the refinement's Jacobian, HAC-corrected).

At the refined point x the prediction errors ``r(x)`` of the logged-input
replay (:mod:`identification.refinement`) are locally linear in x,
``r(x0 + dx) ~ r(x0) + J dx``, so the least-squares estimate moves with the
residual at the truth as ``dx = -(J^T J)^-1 J^T r``.  Its covariance is the
Gauss-Newton *sandwich*

.. math::  \\mathrm{Cov}(\\hat x) = (J^T J)^{-1}\\, S\\, (J^T J)^{-1},
           \\qquad S = \\mathrm{Var}\\Big(\\sum_t s_t\\Big),\\quad s_t = J_t^T r_t

with ``s_t`` the score of sample t (both joints).  For independent residuals
S is ``sigma^2 J^T J`` and the sandwich collapses to the textbook
``sigma^2 (J^T J)^-1`` (``sigma^2 = r^T r / (n - k)``).  Whether the
residuals are independent depends on the log (measured on held-out logs
emulated with known f, ``benchmarks/bench_coverage.py``; the ratio of HAC to
textbook standard errors is reported as ``uncertainty['hac_factor']``):

* rigid robot: the prediction errors are encoder quantisation, of standard
  deviation ~1/sqrt(12) pulse, and their scores are nearly white (lag 2-10
  samples, factor 1.0-1.2);
* flexible joints: the unmodelled ~30 Hz mode leaves correlated residuals
  (lag 30-1300 samples, growing with the encoder resolution), and the
  textbook errors are 3-9 times too small (coverage of f +- 1.96 sd 41 %).

S is therefore estimated by the Newey-West (1987) heteroskedasticity and
autocorrelation consistent estimator with Bartlett weights
``1 - l / (L + 1)``, the lag L chosen by Andrews' (1991, Econometrica 59,
eq. 6.4) AR(1) plug-in rule for the Bartlett kernel,

.. math::  L = 1.1447\\,(\\alpha(1)\\, n)^{1/3},\\qquad
           \\alpha(1) = \\frac{\\sum_a 4\\rho_a^2 / ((1-\\rho_a)^6 (1+\\rho_a)^2)}
                             {\\sum_a 1 / (1-\\rho_a)^4}

with ``rho_a`` the lag-1 autocorrelation of score component a (components
weighted by their inverse innovation variance, so the rule is invariant to
the units of x), capped at n / 4.  The rule follows the data: long-correlated
residuals (coarse encoders, slow motions) get long lags.

Unmodelled dynamics (the flexible case) also *bias* the estimate, which no
variance estimate sees.  Eq. 3 gives a test: a rigid body has f3 = a3 f5 and
f4 = a3 f6, which the nine-parameter search does not enforce; a Wald
statistic far above its chi-squared(2) distribution inflates the covariance
by the Particle Data Group's scale factor (:func:`structure_scale`).  With
both corrections the coverage of f +- 1.96 f_std over 21 held-out logs
(rigid and flexible, 250/1000/4096 ppr, three trajectories) is 96 %
(rigid 93 %, flexible 98 %).

The covariance of f follows through the parameterisation's map f(x) with its
Jacobian (central differences); standard errors of other searched
quantities (payload, initial state) are the square roots of the diagonal.
"""
from __future__ import annotations

import math
import warnings

import numpy as np

from plant.logs.rig import F_NAMES

__all__ = ["hac_lag", "sandwich_covariance", "parameter_uncertainty", "poorly_excited",
           "PoorExcitationWarning", "RSE_WARN", "RESULT_KEYS", "structure_scale",
           "uncertainty_entries", "warning_text"]

#: Result keys written by :func:`uncertainty_entries` (and to the JSON).
RESULT_KEYS = ("f_std", "f_rse", "f_correlation", "x_std", "x_correlation",
               "initial_state_std", "poorly_excited", "uncertainty")

#: Relative standard error above which a parameter is reported as poorly
#: excited by the trajectory (10 %).
RSE_WARN = 0.10

#: Lag-1 autocorrelations are clipped to this value in the lag rule (keeps
#: the AR(1) plug-in finite for a random-walk-like component).
_RHO_MAX = 0.999


class PoorExcitationWarning(UserWarning):
    """An identified parameter's relative standard error exceeds :data:`RSE_WARN`."""


def _scores(jac, residuals, n_channels):
    J = np.asarray(jac, dtype=float)
    r = np.asarray(residuals, dtype=float).ravel()
    if J.ndim != 2 or J.shape[0] != r.size:
        raise ValueError(f"jac must have shape (n_residuals, k) with n_residuals = {r.size}, "
                         f"got {J.shape}")
    if r.size % n_channels:
        raise ValueError(f"{r.size} residuals are not a whole number of samples of "
                         f"{n_channels} channels")
    n = r.size // n_channels
    s = (J * r[:, None]).reshape(n, n_channels, J.shape[1]).sum(axis=1)
    return J, r, s


def hac_lag(scores) -> int:
    """Bartlett lag of the Newey-West estimator by Andrews' AR(1) plug-in rule.

    Parameters
    ----------
    scores : array_like, shape (n, k)
        Per-sample scores ``s_t = J_t^T r_t``.

    Returns
    -------
    int
        L in [0, n // 4].
    """
    s = np.asarray(scores, dtype=float)
    n = s.shape[0]
    s = s - s.mean(axis=0)
    num = den = 0.0
    for a in range(s.shape[1]):
        x0, x1 = s[:-1, a], s[1:, a]
        d = float(x0 @ x0)
        if d <= 0:
            continue
        rho = min(max(float(x0 @ x1) / d, -_RHO_MAX), _RHO_MAX)
        num += 4.0 * rho * rho / ((1 - rho) ** 6 * (1 + rho) ** 2)
        den += 1.0 / (1 - rho) ** 4
    if den == 0:
        return 0
    lag = 1.1447 * (num / den * n) ** (1.0 / 3.0)
    return int(min(math.ceil(lag), n // 4))


def sandwich_covariance(jac, residuals, *, n_channels=2, lag=None):
    """Covariance of the least-squares estimate, Gauss-Newton sandwich with Newey-West S.

    Parameters
    ----------
    jac : array_like, shape (n_channels n, k)
        Jacobian of the residuals at the estimate, rows ordered sample by
        sample (all channels of sample 0, then sample 1, ...).
    residuals : array_like, shape (n_channels n,)
        Residuals at the estimate, same order.
    n_channels : int
        Residuals per sample (2: joints 2 and 3).
    lag : int, optional
        Bartlett lag (samples); default :func:`hac_lag`.  0 gives the
        heteroskedasticity-only (White) estimator.

    Returns
    -------
    cov : ndarray, shape (k, k)
        HAC sandwich covariance of x.
    info : dict
        ``lag``, ``sigma`` (residual standard deviation, sqrt(r^T r/(n-k))),
        ``cov_iid`` (the textbook ``sigma^2 (J^T J)^-1``), ``hac_factor``
        (median ratio of HAC to textbook standard errors), ``dof``.

    Raises
    ------
    ValueError
        On inconsistent shapes or a Jacobian with a zero column.
    """
    J, r, s = _scores(jac, residuals, int(n_channels))
    n, k = s.shape
    d = np.sqrt(np.sum(J * J, axis=0))
    if np.any(d == 0) or not np.all(np.isfinite(J)):
        raise ValueError("the Jacobian has a zero or non-finite column (a parameter the "
                         "residuals do not depend on)")
    # scaled for conditioning: A = D Js^T Js D
    Js = J / d
    Ainv_s = np.linalg.pinv(Js.T @ Js)
    ss = s / d
    L = hac_lag(ss) if lag is None else int(lag)
    if L < 0:
        raise ValueError(f"lag must be >= 0, got {lag}")
    sc = ss - ss.mean(axis=0)
    S = ss.T @ ss
    for lag_ in range(1, min(L, n - 1) + 1):
        G = sc[lag_:].T @ sc[:-lag_]
        S += (1.0 - lag_ / (L + 1.0)) * (G + G.T)
    cov_s = Ainv_s @ S @ Ainv_s
    dof = max(r.size - k, 1)
    sigma2 = float(r @ r) / dof
    cov_iid_s = sigma2 * Ainv_s
    cov = cov_s / np.outer(d, d)
    cov_iid = cov_iid_s / np.outer(d, d)
    ratio = np.sqrt(np.maximum(np.diag(cov_s), 0) / np.maximum(np.diag(cov_iid_s), 1e-300))
    return cov, dict(lag=L, sigma=math.sqrt(sigma2), cov_iid=cov_iid,
                     hac_factor=float(np.median(ratio)), dof=dof)


def _map_jacobian(to_f, x):
    """Central-difference Jacobian (9, k) of the parameterisation's map at x."""
    x = np.asarray(x, dtype=float)
    h = 1e-6 * np.maximum(np.abs(x), 1e-3)
    P = np.vstack([x + np.diag(h), x - np.diag(h)])
    F = np.asarray(to_f(P), dtype=float).reshape(2 * x.size, -1)
    return ((F[:x.size] - F[x.size:]) / (2 * h[:, None])).T


def correlation_matrix(cov):
    sd = np.sqrt(np.maximum(np.diag(cov), 0))
    with np.errstate(invalid="ignore", divide="ignore"):
        c = cov / np.outer(sd, sd)
    return np.where(np.outer(sd, sd) > 0, c, 0.0)


def structure_scale(f, f_cov, a3):
    """Model-adequacy scale factor from eq. 3's identities f3 = a3 f5, f4 = a3 f6.

    Both identities hold for every rigid PUMA links 2-3 (``m3 x3 a3`` and
    ``m3 y3 a3``), but the nine-parameter search does not enforce them.  The
    Wald statistic ``W = g^T Cov(g)^-1 g`` of ``g = (f3 - a3 f5, f4 - a3 f6)``
    is chi-squared with 2 degrees of freedom when the model describes the
    log; a larger W means an unmodelled effect (joint flexibility, backlash)
    biases the estimate beyond its statistical error.  The covariance is
    then inflated by ``W / 2`` (the scale-factor rule of the Particle Data
    Group for inconsistent measurements, Review of Particle Physics,
    Introduction, sec. 5.2).

    Parameters
    ----------
    f : array_like, shape (9,)
        Estimate.
    f_cov : array_like, shape (9, 9)
        Its covariance.
    a3 : float
        Link length a3 (m).

    Returns
    -------
    scale : float
        ``sqrt(max(1, W / 2))`` (1 when the identities are enforced by the
        parameterisation, i.e. Cov(g) vanishes).
    wald : float or None
        W (None when not testable).
    """
    B = np.zeros((2, 9))
    B[0, 2], B[0, 4], B[1, 3], B[1, 5] = 1.0, -a3, 1.0, -a3
    f = np.asarray(f, dtype=float)
    C = np.asarray(f_cov, dtype=float)
    Vg = B @ C @ B.T
    ref = np.max(np.abs(np.diag(C))[[2, 3, 4, 5]]) + 1e-300
    if np.linalg.eigvalsh(Vg)[0] <= 1e-10 * ref:
        return 1.0, None
    g = B @ f
    W = float(g @ np.linalg.solve(Vg, g))
    return math.sqrt(max(1.0, W / 2.0)), W


def parameter_uncertainty(jac, residuals, x, to_f, *, n_channels=2, lag=None, a3=None):
    """Standard errors and correlations of x and of f = to_f(x).

    Parameters
    ----------
    jac : array_like, shape (n_residuals, k)
        Jacobian of the residuals at x (:attr:`RefineResult.jac`).
    residuals : array_like, shape (n_residuals,)
        Residuals at x.
    x : array_like, shape (k,)
        The estimate (parameters first; trailing nuisance components, e.g.
        an estimated initial state, are allowed: ``to_f`` sees only its
        first ``k_f`` columns, as given by its own input).
    to_f : callable
        ``to_f(X) -> F`` for X of shape (m, k), F of shape (m, 9).
    n_channels : int
        Residuals per sample.
    lag : int, optional
        Bartlett lag (default: the plug-in rule).
    a3 : float, optional
        Link length a3 (m): apply the model-adequacy scale factor of
        :func:`structure_scale` (``info['scale']``, ``info['wald']``).

    Returns
    -------
    dict
        ``x_std`` (k,), ``x_cov`` (k, k), ``x_correlation`` (k, k),
        ``f`` (9,), ``f_std`` (9,), ``f_cov`` (9, 9), ``f_correlation``
        (9, 9), ``f_rse`` (9,) (relative standard errors ``f_std / |f|``),
        and ``info`` (see :func:`sandwich_covariance`).
    """
    x = np.asarray(x, dtype=float)
    cov, info = sandwich_covariance(jac, residuals, n_channels=n_channels, lag=lag)
    G = _map_jacobian(to_f, x)
    f = np.asarray(to_f(x[None]), dtype=float).reshape(9)
    f_cov = G @ cov @ G.T
    scale, wald = (1.0, None) if a3 is None else structure_scale(f, f_cov, float(a3))
    cov, f_cov = cov * scale ** 2, f_cov * scale ** 2
    info.update(scale=scale, wald=wald)
    f_std = np.sqrt(np.maximum(np.diag(f_cov), 0))
    with np.errstate(divide="ignore", invalid="ignore"):
        rse = f_std / np.abs(f)
    return dict(x_std=np.sqrt(np.maximum(np.diag(cov), 0)), x_cov=cov,
                x_correlation=correlation_matrix(cov), f=f, f_std=f_std, f_cov=f_cov,
                f_correlation=correlation_matrix(f_cov), f_rse=rse, info=info)


def poorly_excited(f_rse, names=F_NAMES, threshold=RSE_WARN):
    """Names of the parameters whose relative standard error exceeds ``threshold``.

    Parameters
    ----------
    f_rse : array_like
        Relative standard errors.
    names : sequence of str
        Their names (default f1..f9).
    threshold : float
        Default :data:`RSE_WARN` (10 %).

    Returns
    -------
    list of str
    """
    rse = np.asarray(f_rse, dtype=float)
    return [n for n, v in zip(names, rse) if not (v <= threshold)]


def warning_text(names, f_rse, threshold=RSE_WARN, all_names=F_NAMES):
    """The one-line warning naming the poorly excited parameters (empty if none).

    Parameters
    ----------
    names : list of str
        Output of :func:`poorly_excited`.
    f_rse : array_like, shape (9,)
        Relative standard errors of f1..f9 (or of the parameters named
        ``all_names``).
    threshold : float
        The threshold used.
    all_names : sequence of str
        The names of ``f_rse``'s entries (default f1..f9; the payload's
        ``m, xp, yp, Jc`` in payload mode).

    Returns
    -------
    str
    """
    if not names:
        return ""
    rse = dict(zip(all_names, np.asarray(f_rse, dtype=float)))
    items = ", ".join(f"{n} ({100 * rse[n]:.0f} %)" if n in rse else n for n in names)
    return (f"relative standard error above {100 * threshold:.0f} %: {items} -- "
            "poorly excited by this trajectory")


def uncertainty_entries(jac, residuals, x, to_f, *, k, names, a3=None, warn=True,
                        judge_x=False):
    """Result entries of :func:`identification.identify` (and the warning).

    Parameters
    ----------
    jac, residuals : ndarray or None
        The refinement's final Jacobian and residuals (None: no entries).
    x : ndarray, shape (k + n_state,)
        Refined vector (searched parameters, then an estimated initial
        state if any).
    to_f : callable
        Map of the searched parameters (first k columns) to f.
    k : int
        Number of searched parameters.
    names : list of str
        Names of the searched parameters.
    a3 : float, optional
        Link length (m): apply :func:`structure_scale`.
    warn : bool
        Issue a :class:`PoorExcitationWarning` naming every parameter of f
        whose relative standard error exceeds :data:`RSE_WARN`.
    judge_x : bool
        Judge the excitation on the searched parameters ``names`` instead of
        f (payload mode: the user asked for ``m, xp, yp, Jc``, not for f).

    Returns
    -------
    dict
        ``f_std``, ``f_rse``, ``f_correlation``, ``x_std``,
        ``x_correlation``, ``initial_state_std`` (with an estimated state),
        ``poorly_excited`` (names), ``poorly_excited_rse`` (the relative
        standard errors they were judged on, named in
        ``uncertainty["rse_names"]``) and ``uncertainty`` (method, lag,
        hac_factor, sigma); empty if the Jacobian is missing or singular.
    """
    if jac is None or residuals is None:
        return {}
    try:
        u = parameter_uncertainty(jac, residuals, x, lambda X: to_f(np.atleast_2d(X)[:, :k]),
                                  a3=a3)
    except (ValueError, np.linalg.LinAlgError):
        return {}
    if judge_x:
        xk = np.abs(np.asarray(x, dtype=float)[:k])
        with np.errstate(divide="ignore", invalid="ignore"):
            rse = np.where(xk > 0, np.asarray(u["x_std"][:k], dtype=float) / xk, np.inf)
        rse_names = list(names)
    else:
        rse, rse_names = np.asarray(u["f_rse"], dtype=float), list(F_NAMES)
    bad = poorly_excited(rse, names=rse_names)
    out = dict(f_std=u["f_std"], f_rse=u["f_rse"], f_correlation=u["f_correlation"],
               x_std=u["x_std"][:k], x_correlation=u["x_correlation"][:k, :k],
               poorly_excited=bad, poorly_excited_rse=rse,
               uncertainty=dict(method="Gauss-Newton sandwich, Newey-West (Bartlett) HAC",
                                lag=u["info"]["lag"], hac_factor=u["info"]["hac_factor"],
                                sigma_pulses=u["info"]["sigma"], x_names=list(names),
                                scale=u["info"]["scale"], wald=u["info"]["wald"],
                                rse_threshold=RSE_WARN, rse_names=rse_names))
    if np.size(x) > k:
        out["initial_state_std"] = u["x_std"][k:]
    if warn and bad:
        warnings.warn(warning_text(bad, rse, all_names=rse_names), PoorExcitationWarning,
                      stacklevel=3)
    return out
