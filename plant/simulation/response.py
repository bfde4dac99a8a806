"""Time response of a sampled closed loop (:func:`plant.simulate_closed_loop`)."""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

__all__ = ["ClosedLoopResponse"]


@dataclass(frozen=True)
class ClosedLoopResponse:
    """Time response of a sampled closed loop (one value per controller sample).

    Modelled on :class:`control.TimeResponseData`: the raw arrays are stored
    time-first, and the properties :attr:`time`, :attr:`outputs`,
    :attr:`inputs`, :attr:`states` give them signal-first as python-control
    does (``outputs`` are the pulse errors, ``inputs`` the currents, ``states``
    the joint angles and rates).  :meth:`to_time_response` converts to a real
    :class:`control.TimeResponseData`.

    Attributes
    ----------
    t : ndarray, shape (n,)
        Sample times t_k = k Ts (s).
    q : ndarray, shape (n, n_joints)
        True joint angles at t_k (rad) (link side for a flexible robot).
    qd : ndarray, shape (n, n_joints)
        True joint rates at t_k (rad/s).
    q_ref : ndarray, shape (n, n_joints)
        Reference angles at t_k (rad).
    e_pulses : ndarray, shape (n, n_joints), int64
        Pulse errors ``trunc(q_ref k N/2pi) - trunc(q_enc k N/2pi)`` at t_k,
        where ``q_enc`` is the angle the encoder sees (the motor angle / k for
        a flexible robot).
    i_A : ndarray, shape (n, n_joints)
        Motor currents applied over [t_k, t_k + Ts) (A), after clipping.
    success : bool
        False when the simulation stopped early (then the arrays hold only the
        samples simulated before the failure).
    message : str
        "ok" or the reason of the failure.
    label : str
        Free-text label (controller name) used in plots.
    n_clipped : int
        Samples at which a current was at the drive's full scale
        (``current_full_scale_A``): saturated by the controller itself or
        clipped by the drive.
    joint_names : tuple of str
        Names of the joints (default ``("q2", "q3")``, the PUMA links 2-3;
        the ``joint_names`` of a :class:`~plant.robot.robot_model.RobotModel`).
    """

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    q_ref: np.ndarray
    e_pulses: np.ndarray
    i_A: np.ndarray
    success: bool = True
    message: str = "ok"
    label: str = ""
    n_clipped: int = field(default=0)
    joint_names: tuple = ("q2", "q3")

    def _suffixes(self) -> list:
        return [name[1:] if name.startswith("q") else name for name in self.joint_names]

    # python-control style accessors (signal-first)
    @property
    def time(self) -> np.ndarray:
        """Sample times (n,), s."""
        return self.t

    @property
    def outputs(self) -> np.ndarray:
        """Pulse errors, shape (n_joints, n) (python-control layout)."""
        return self.e_pulses.T

    @property
    def inputs(self) -> np.ndarray:
        """Motor currents, shape (n_joints, n), A."""
        return self.i_A.T

    @property
    def states(self) -> np.ndarray:
        """Joint angles and rates (q2, q3, qd2, qd3 for the PUMA), shape (2 n_joints, n)."""
        return np.vstack([self.q.T, self.qd.T])

    def to_time_response(self):
        """Return the response as a :class:`control.TimeResponseData`.

        Returns
        -------
        control.TimeResponseData
            outputs ``e2, e3`` (pulses), inputs ``i2, i3`` (A), states
            ``q2, q3, qd2, qd3``.
        """
        import control

        return control.TimeResponseData(
            self.t, self.outputs.astype(float), self.states, self.inputs,
            output_labels=[f"e{s}" for s in self._suffixes()],
            input_labels=[f"i{s}" for s in self._suffixes()],
            state_labels=[f"q{s}" for s in self._suffixes()] + [f"qd{s}" for s in self._suffixes()],
            title=self.label or None,
            success=self.success, message=self.message,
        )

    # ------------------------------------------------------------- statistics
    def _mask(self, after_s: float) -> np.ndarray:
        after_s = float(after_s)
        if not math.isfinite(after_s):
            raise ValueError(f"after_s must be finite, got {after_s!r}")
        m = self.t >= after_s - 1e-12
        if not np.any(m):
            raise ValueError(f"no sample at or after {after_s} s (run ends at {self.t[-1]:.4f} s)")
        return m

    def max_abs_error(self, after_s: float = 0.0) -> np.ndarray:
        """Largest abs(e) per joint over the samples with t >= after_s.

        Parameters
        ----------
        after_s : float
            Start of the evaluated part of the run (s).

        Returns
        -------
        ndarray, shape (n_joints,), int64
            max abs(e) (pulses) per joint.

        Raises
        ------
        ValueError
            If no sample lies at or after ``after_s``.
        """
        return np.max(np.abs(self.e_pulses[self._mask(after_s)]), axis=0)

    def rms_error(self, after_s: float = 0.0) -> np.ndarray:
        """Root-mean-square pulse error per joint over t >= after_s.

        Parameters
        ----------
        after_s : float
            Start of the evaluated part of the run (s).

        Returns
        -------
        ndarray, shape (n_joints,), float (pulses)
        """
        e = self.e_pulses[self._mask(after_s)].astype(float)
        return np.sqrt(np.mean(e * e, axis=0))

    def within(self, pulses: int = 1, after_s: float = 0.0) -> bool:
        """Whether abs(e) <= pulses on every joint for every sample with t >= after_s.

        A run that failed (``success`` False) is never within.

        Parameters
        ----------
        pulses : int
            Tolerance (pulses).
        after_s : float
            Start of the evaluated part of the run (s).

        Returns
        -------
        bool
        """
        return bool(self.success and np.all(self.max_abs_error(after_s) <= pulses))

    # --------------------------------------------------------------- plotting
    def plot(self, *, currents: bool = True, title: str | None = None, ax=None):
        """Plot the pulse errors (and currents) per joint.

        Parameters
        ----------
        currents : bool
            Add a row with the motor currents.
        title : str, optional
            Figure title (default: the label).
        ax : ndarray of matplotlib.axes.Axes, optional
            Axes to draw into, shape (rows, n_joints) with rows = 2 if
            ``currents`` else 1; default: a new figure.

        Returns
        -------
        matplotlib.figure.Figure
            The figure holding the axes; never shown (no ``plt.show()``).

        Raises
        ------
        ValueError
            If ``ax`` does not hold rows x n_joints axes.
        """
        rows = 2 if currents else 1
        nj = self.e_pulses.shape[1]
        if ax is None:
            from matplotlib.figure import Figure

            fig = Figure(figsize=(5 * nj, 3.2 * rows), layout="constrained")
            axes = fig.subplots(rows, nj, sharex=True, squeeze=False)
        else:
            axes = np.asarray(ax, dtype=object).reshape(-1, nj) if np.size(ax) == nj * rows else None
            if axes is None:
                raise ValueError(f"ax must hold {rows} x {nj} axes, got {np.size(ax)}")
            fig = axes[0, 0].figure
        for j, name in enumerate(f"joint {s}" for s in self._suffixes()):
            a = axes[0, j]
            a.step(self.t, self.e_pulses[:, j], where="post", lw=0.8)
            a.set_ylabel("e (pulses)")
            a.set_title(f"{name}: max |e| {self.max_abs_error()[j]} pulses")
            a.grid(True, alpha=0.3)
            if currents:
                a = axes[1, j]
                a.step(self.t, self.i_A[:, j], where="post", lw=0.8, color="C1")
                a.set_ylabel("i (A)")
                a.grid(True, alpha=0.3)
            axes[-1, j].set_xlabel("t (s)")
        fig.suptitle(title if title is not None else (self.label or "closed-loop response"))
        return fig
