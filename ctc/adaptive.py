"""On-line payload identification and adaptation under computed-torque control.

The paper's closing proposal, in three stages, as one sampled controller
(:class:`AdaptiveComputedTorqueController`):

1. run the CTC with the unloaded robot's identified model (the *prior*) and
   keep the last window (``window_s``, default 200 ms) of its own
   measurements, pulse errors, commands and estimator states;
2. identify the payload on that window with the CTC itself in the loop
   (:func:`identification.identify` with ``payload=True``: the window has
   no start state, so the model starts at its first sample from a state
   estimated from the window and refined as nuisance parameters; the
   refinement replays the logged commands, the output error simulates the
   CTC in the loop through the compiled law of :mod:`plant.controllers`);
3. put the identified load into the CTC (D_hat, h_hat, g_hat of ``prior +
   payload``) -- but only once the identification's latency has passed on
   the controller's own sample clock: a fixed ``latency_s`` (default, so a
   simulation repeats bit for bit) or the measured wall time
   (``latency_s='measured'``, hardware).  The kernels are compiled when the
   controller is built, never inside the loop.

When to identify: every window, back to back.  A correct model tracks to
+-1 pulse, so a small payload (0.5 kg) shows in the errors only as a bias
inside that band, which a threshold on the error would not see; identifying
every window costs one identification per window (<= 0.2 s of one core per
0.2 s window) and finds the change within two windows of the pick-up.
False updates are kept out by a test on the window itself: an estimate is
accepted only when the CTC-in-the-loop output error (paper eq. 4) of the
robot with it is clearly below that of the current model
(``improvement``), so a window without a change (or without excitation)
leaves the model alone.

Real hardware: the sample loop must never wait for an identification.
There a background worker (a thread or a second core) takes each completed
window, identifies it and posts the result; the sample loop switches the
model at the first sample after the post.  In simulation the identification
runs synchronously at the window's end and its latency (fixed, or the
measured wall time) delays the switch by as many samples -- the same timing
as the worker, and the worker is busy for that time (a window completed
while it is busy is skipped).
"""
from __future__ import annotations

import dataclasses
import math
import time

import numpy as np

from .computed_torque import ComputedTorqueController, reference_of

__all__ = ["AdaptiveComputedTorqueController", "DEFAULT_LATENCY_S"]

#: Default identification latency (s): the per-window budget of a 200 ms window
#: (``benchmarks/bench_online_payload.py`` measures 0.01-0.07 s per window on the
#: development machine), fixed so that simulations repeat bit for bit.
DEFAULT_LATENCY_S = 0.2


def _refuse_flexible_prior(prior):
    """A flexible identification cannot be this controller's prior: say so in one line.

    The adaptive CTC runs the rigid CTC and identifies the payload with the
    rigid plant in the loop; reducing a two-mass prior to its rigid-equivalent
    f would drop K, D and Jm k^2 silently (issue 21, item 2).
    """
    import os

    d = prior
    if isinstance(prior, (str, os.PathLike)):
        from plant.fileio import read_json_object

        d = read_json_object(prior, "prior result file")
    model = d.get("model") if isinstance(d, dict) else getattr(d, "get", lambda k: None)("model")
    if model is not None and model != "rigid":
        raise ValueError(f"the adaptive CTC takes a rigid prior; this prior's model is {model!r} "
                         "(use ComputedTorqueController.from_result for a flexible robot, or "
                         "identify the prior with model='rigid')")


class AdaptiveComputedTorqueController:
    """CTC that identifies its payload on-line and adapts D_hat, h_hat, g_hat.

    Build it with :meth:`from_log`; it follows the sampled-controller
    protocol (``reset()``, ``__call__(k, t, q_meas, e_pulses) -> (2,)`` A).
    See the module docstring for the three stages and their timing.

    Parameters
    ----------
    prior_f : array_like, shape (9,)
        The unloaded robot's f.
    log : plant.ExperimentLog
        Rig and reference (as :meth:`ctc.ComputedTorqueController.from_log`).
    window_s : float
        Length of the identification window (s).
    improvement : float
        An estimate is accepted when its windowed output error is below
        ``(1 - improvement)`` times the current model's.
    latency_s : float or 'measured'
        Delay (s) from a window's end to its model taking effect.  A number
        (default :data:`DEFAULT_LATENCY_S`, the per-window budget) makes a
        simulation repeat bit for bit; ``'measured'`` uses the measured wall
        time of each identification (hardware: the worker's real delay).
    identify_options : dict, optional
        Extra keyword arguments of :func:`identification.identify`.
    trajectory : plant.trajectory.Trajectory, optional
        The reference to follow (default the log's).
    **ctc_options
        Keyword arguments of :meth:`ctc.ComputedTorqueController.from_log`
        (gains, estimator, ...).

    Attributes
    ----------
    prior_f : ndarray, shape (9,)
    f : ndarray, shape (9,)
        The model in use.
    payload_history : list of (float, float)
        ``(t_s, mass_kg)`` per accepted identification, ``t_s`` the time the
        new model took effect.
    identifications : list of dict
        Every identification: window, wall time, mass, output errors,
        accepted.

    Raises
    ------
    ValueError
        On a bad prior, window or option, or a flexible prior (the inner
        controller is the rigid CTC: a two-mass prior is refused, never
        reduced to its rigid-equivalent f).
    """

    def __init__(self, prior_f, log, *, window_s=0.2, improvement=0.2,
                 latency_s=DEFAULT_LATENCY_S, identify_options=None, trajectory=None,
                 **ctc_options):
        from identification.parameters import prior_f as as_prior_f

        _refuse_flexible_prior(prior_f)
        self.prior_f = as_prior_f(prior_f)
        ts = float(log.rig.sample_time_s)
        if not (np.isfinite(window_s) and window_s >= 20 * ts):
            raise ValueError(f"window_s must be at least 20 samples ({20 * ts} s), got {window_s!r}")
        if not 0.0 <= improvement < 1.0:
            raise ValueError(f"improvement must be in [0, 1), got {improvement!r}")
        if latency_s is None:
            latency_s = DEFAULT_LATENCY_S
        if not (latency_s == "measured" or (isinstance(latency_s, (int, float))
                                            and np.isfinite(latency_s) and latency_s >= 0)):
            raise ValueError(f"latency_s must be a number >= 0 (s) or 'measured', got {latency_s!r}")
        self.log = log
        self.window_s = float(window_s)
        self.improvement = float(improvement)
        self.latency_s = latency_s if latency_s == "measured" else float(latency_s)
        self.identify_options = dict(identify_options or {})
        self._ts = ts
        self._n_window = int(round(self.window_s / ts))
        self.trajectory = reference_of(log, trajectory)
        self._ctc = ComputedTorqueController.from_log(self.prior_f, log, trajectory=self.trajectory,
                                                      **ctc_options)
        self._window_rig = dataclasses.replace(log.rig, q0_rad=None, qd0_rad_per_s=None,
                                               payload_mass_kg=None)
        self.reset()
        self._compile()

    def _compile(self):
        """Compile (or load) every kernel a window identification uses, now, not in the loop.

        One identification of a still window (zero errors and currents) with
        the CTC in the loop; its outcome is discarded.
        """
        import warnings

        import identification

        n = self._n_window
        rows = [(k, 0, 0, 0.0, 0.0, self._ctc.estimator_state(), self.f) for k in range(n)]
        window = self.window_log(rows)
        law = self._ctc.logged_controller(window, state=rows[0][5])
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                identification.identify(window, payload=True, prior=self.prior_f, controller=law,
                                        rng=0, progress=False, workers=1,
                                        refine_options=dict(max_iter=1, n_starts=1))
            except ValueError:
                pass  # a still window may be refused; the kernels are compiled by then

    @classmethod
    def from_log(cls, prior, log, *, window_s=0.2, **options):
        """The adaptive CTC of a log's rig and reference, from the unloaded robot's model.

        Parameters
        ----------
        prior : IdentificationResult, dict with ``'f'``, path of a result JSON, or array_like (9,)
            The unloaded robot's identification (or its f).
        log : plant.ExperimentLog
            Rig constants and reference trajectory.
        window_s : float
            Identification window (s), default 0.2.
        **options
            ``improvement``, ``latency_s``, ``identify_options``,
            ``trajectory`` (any reference; default the log's) and the
            keywords of :meth:`ctc.ComputedTorqueController.from_log`.

        Returns
        -------
        AdaptiveComputedTorqueController
        """
        return cls(prior, log, window_s=window_s, **options)

    # ------------------------------------------------------------ protocol
    def reset(self) -> None:
        """Back to the prior model; forget the window, the history and any pending model."""
        self._ctc.reset()
        self._ctc.f = np.ascontiguousarray(self.prior_f)
        self.f = self._ctc.f
        self.payload = None
        self.payload_history = []
        self.identifications = []
        self._pending = None  # (k_effective, f, payload dict)
        self._busy_until = -1
        self._rows = []
        self._window_start = 0

    def __call__(self, k, t, q_meas, e_pulses) -> np.ndarray:
        """Motor currents (2,) A for sample ``k`` (see the module docstring).

        Parameters
        ----------
        k : int
            Sample index from the start of the run (in order after :meth:`reset`).
        t : float
            Sample time (s).
        q_meas : ndarray, shape (2,)
            Quantised joint angles (rad).
        e_pulses : ndarray, shape (2,)
            Pulse errors ``ref - act``.

        Returns
        -------
        ndarray, shape (2,)
        """
        if self._pending is not None and k >= self._pending[0]:
            _, f, payload = self._pending
            self._ctc.f = np.ascontiguousarray(f)
            self.f = self._ctc.f
            self.payload = payload
            self.payload_history.append((k * self._ts, payload["mass_kg"]))
            self._pending = None
        state = self._ctc.estimator_state()
        i = self._ctc(k, t, q_meas, e_pulses)
        if not self._rows:
            self._window_start = k
        self._rows.append((k, e_pulses[0], e_pulses[1], i[0], i[1], state, self.f))
        if len(self._rows) >= self._n_window:
            rows, self._rows = self._rows, []
            if k >= self._busy_until and self._pending is None:
                self._identify(rows, k)
        return i

    # ------------------------------------------------------------ stage 2
    def window_log(self, rows=None):
        """The window of the controller's own records as a log without a start state.

        Parameters
        ----------
        rows : list, optional
            Records (default: the window being collected).

        Returns
        -------
        plant.ExperimentLog
        """
        rows = self._rows if rows is None else rows
        if not rows:
            raise ValueError("no samples recorded yet")
        k = np.array([r[0] for r in rows])
        t = k * self._ts
        e = np.array([[r[1], r[2]] for r in rows], dtype=np.int64)
        i = np.array([[r[3], r[4]] for r in rows], dtype=float)
        return self.log.replace(
            name=f"ctc_window_{t[0]:.3f}s", t=t, q_ref=self.trajectory.position(t),
            trajectory=self.trajectory,
            e_pulses=e, i_A=i, rig=self._window_rig, start_index=int(k[0]),
            window_s=(float(t[0]), float(t[-1] + self._ts)))

    def _identify(self, rows, k_end):
        import identification
        import plant

        t0 = time.perf_counter()
        window = self.window_log(rows)
        f_used = rows[0][6]
        if any(r[6] is not f_used for r in rows):
            return  # the model changed inside the window: not one controller
        law = self._ctc.logged_controller(window, state=rows[0][5])
        law = dataclasses.replace(law, parameters=law.parameters._replace(f=np.ascontiguousarray(f_used)))
        opts = dict(rng=0, progress=False, workers=1)
        opts.update(self.identify_options)
        import warnings

        with warnings.catch_warnings(record=True) as caught:  # kept in the record, not raised
            warnings.simplefilter("always")
            res = identification.identify(window, payload=True, prior=self.prior_f,
                                          controller=law, **opts)
        x0 = res.refinement["initial_state"]
        # the current model's output error from the same start, the CTC in the loop
        y_now = float(plant.simulate_batch(window, self.f[None], substeps=res.settings["substeps"],
                                           errors=False, workers=1, initial_state=x0,
                                           controller=law).objective[0])
        wall = time.perf_counter() - t0
        accepted = bool(res.fun < (1.0 - self.improvement) * y_now)
        mass = float(res.payload["mass_kg"])
        self.identifications.append(dict(window_s=window.window_s, wall_time_s=wall,
                                         mass_kg=mass, fun=float(res.fun), fun_current=y_now,
                                         accepted=accepted,
                                         warnings=[str(w.message) for w in caught]))
        latency = wall if self.latency_s == "measured" else self.latency_s
        k_eff = k_end + 1 + int(math.ceil(latency / self._ts))
        self._busy_until = k_eff
        if accepted:
            self._pending = (k_eff, np.asarray(res.f, dtype=float), dict(res.payload))

    @property
    def payload_mass_kg(self):
        """Mass (kg) of the payload in the current model (0.0 before any accepted identification)."""
        return 0.0 if self.payload is None else float(self.payload["mass_kg"])

    def __repr__(self) -> str:
        return (f"AdaptiveComputedTorqueController(window_s={self.window_s}, "
                f"payload_mass_kg={self.payload_mass_kg:.4g}, "
                f"identifications={len(self.identifications)})")
