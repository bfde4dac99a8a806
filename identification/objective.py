"""The identification objective: the output error of paper eq. 4.

``Y(f) = sum_i sum_j (e_ij^robot - e_ij^model(f))^2`` in pulses^2, the model
errors coming from :func:`plant.simulate_batch` (the exact closed-loop
simulation of the logged P-control experiment on the log's own rig,
trajectory and start state), vectorised and parallel over a population.
"""
from __future__ import annotations

import numpy as np

import plant
from plant import STATUS_OK

from .filtering import apply_lowpass, lowpass_sos

__all__ = ["OutputError", "IDENTIFICATION_SUBSTEPS"]

#: RK4 substeps per sample used while identifying.  The integer output error
#: is dominated by whole-pulse flips of the (chaotic) quantised loop: any f
#: more than ~1e-7 away from the truth sees an output-error floor of ~1000
#: pulses^2 on the paper log whatever the substeps, so the identification
#: integrates with one RK4 step per sample (0.7 ms; stable for every model in
#: the search ranges that the sampled P loop itself can hold) and keeps the
#: converged simulation (:data:`plant.DEFAULT_SUBSTEPS`) for reproducing logs.
#: Measured on the paper log: 1 and 2 substeps identify f1 f2 f4 f6 f7 f9 to
#: the same 0.03 %, at half the cost.
IDENTIFICATION_SUBSTEPS = 1


class OutputError:
    """Output error (paper eq. 4) of a log as a population objective.

    Parameters
    ----------
    log : plant.ExperimentLog
        The logged experiment.
    substeps : int
        RK4 substeps per sample of the simulation.
    lowpass_hz : float, optional
        If given, the logged and the simulated errors are low-passed with the
        same zero-phase Butterworth filter before the sum of squares
        (:mod:`identification.filtering`).
    workers : int, optional
        Threads of the parallel simulation.
    initial_state : array_like, shape (4,), optional
        State at the log's first sample: the simulation starts there instead
        of at t = 0 (a window without a start state).
    controller : object, optional
        The controller that ran, simulated in the loop (see
        :func:`plant.simulate_batch`; default the rig's P law).
    plant : plant.simulation.plants.Plant, optional
        The simulated plant (default rigid); per-candidate parameters beyond
        f go to a call's ``plant_parameters``.

    Notes
    -----
    Candidates that fail (D(q) not positive definite, divergence) receive the
    finite penalty documented in :mod:`plant.simulation.simulate`, so a rank-based
    optimiser can still order them; ``last_status`` holds the status codes
    (:data:`plant.simulation.core.STATUS_OK`, ...) of the last call's candidates.  ``nfev``
    counts simulated candidates.
    """

    def __init__(self, log, *, substeps=IDENTIFICATION_SUBSTEPS, lowpass_hz=None, workers=None,
                 initial_state=None, controller=None, plant=None):
        self.log = log
        self.controller = controller
        self.initial_state = initial_state
        self.plant = plant
        self.substeps = int(substeps)
        self.workers = workers
        self.lowpass_hz = None if lowpass_hz is None else float(lowpass_hz)
        self.nfev = 0
        self.last_status = None
        if self.lowpass_hz is not None:
            self._sos = lowpass_sos(self.lowpass_hz, log.rig.sample_time_s)
            self._e_log_filtered = apply_lowpass(log.e_pulses, self._sos)

    def __call__(self, F, cap=None, initial_state=None, plant_parameters=None):
        """Output errors of candidates ``F`` (m, 9) -> (m,) pulses^2.

        ``initial_state`` ((4,) or (m, 4), optional) overrides the one given
        at construction for this call.

        ``cap`` (pulses^2, optional) terminates candidates early once their
        running output error passes it (see :func:`plant.simulate_batch`);
        their value is then the running sum extrapolated to the whole log,
        above ``cap``.  With a low-pass filter the errors are filtered over
        the whole run, so the cap is not applied.  ``plant_parameters``
        (dict, optional): the candidates' plant parameters beyond f
        (:func:`plant.simulate_batch`).
        """
        F = np.atleast_2d(np.asarray(F, dtype=float))
        filtered = self.lowpass_hz is not None
        sim = plant.simulate_batch(
            self.log, F, substeps=self.substeps, errors=filtered, workers=self.workers,
            cap=None if filtered else cap,
            initial_state=self.initial_state if initial_state is None else initial_state,
            controller=self.controller, plant=self.plant, plant_parameters=plant_parameters,
        )
        self.nfev += F.shape[0]
        self.last_status = sim.status  # per candidate (plant.STATUS_OK, ...), for the callers
        if not filtered:
            return sim.objective
        d = apply_lowpass(sim.e_pulses, self._sos) - self._e_log_filtered[None]
        y = np.einsum("mnj,mnj->m", d, d)
        failed = sim.status != STATUS_OK
        y[failed] = sim.objective[failed]
        return y

    def errors(self, f):
        """Simulated tracking errors of one candidate.

        Parameters
        ----------
        f : array_like, shape (9,)
            Base parameters.

        Returns
        -------
        ndarray, shape (n_samples, 2), int64 (pulses)
        """
        self.nfev += 1
        return plant.simulate_experiment(self.log, f, substeps=self.substeps,
                                         initial_state=self.initial_state,
                                         controller=self.controller)
