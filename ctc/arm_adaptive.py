"""Adaptive computed-torque control of any serial arm: a payload identified on-line.

The paper's proposal (sec. 5: identify a carried load from a 100-200 ms
window and feed it to the computed-torque controller), for a robot model of
n joints (:class:`plant.robot.robot_model.RobotModel`), with the safety
rules of the PUMA path's supervisor (:mod:`ctc.adaptive`, issue 21), on a
rigid or a two-mass flexible prior (the last paragraph):

1. **Windows.**  The inner controller is the arm's computed torque
   (:class:`ctc.arm.ArmComputedTorque`, with its current limit and its
   following-error watchdog).  Every ``window_s`` of the run the controller
   identifies the payload on the chain's last link from its own window:
   :func:`identification.arm_payload.identify_arm_payload` with the
   currents it commanded (``currents="logged"``: the controller knows what
   the drive applied, the replay needs no model of the controller), the
   unloaded prior's base parameters, and the window's start state refined
   as nuisance parameters.  The model in use is fitted the same way (its
   payload pinned, the start state free), so the two are compared on equal
   terms: on a two-mass arm it starts from the link start box the free fit
   ended in, and when it had to widen that box (links ringing beyond it,
   :mod:`identification.arm_payload`) the free fit is fitted again in the
   wider one, the lower cost kept -- else the pinned fit could search where
   the free one did not.  (The free fit's starts can still miss the pinned
   one's minimum: a likelihood ratio a little below zero reads "no
   change".)
2. **Significance.**  The estimate replaces the model in use only when it
   explains the window better than the quantisation noise can account for:
   the likelihood ratio of :func:`ctc.adaptive.residual_statistics` (the
   difference of the two output errors over the residual variance, floored
   at :data:`ctc.adaptive.QUANTISATION_VARIANCE`, and the residual's
   autocorrelation time) beyond the chi-square quantile of ``false_alarm``
   with as many degrees of freedom as the window identifies payload
   parameters (Basseville & Nikiforov, *Detection of Abrupt Changes*,
   1993, sec. 2.4).
3. **Plausibility and adequacy.**  An estimate at the upper end of the
   mass box is the optimiser's, not the robot's (decision
   ``'implausible'``); a significant change whose best payload still leaves
   the window's output error above
   :data:`identification.flexible.INADEQUATE_FACTOR` quantisation floors is
   a change a payload does not describe (friction, damping, a collision:
   decision ``'unexplained'``).  **The rivals**: before an update to another
   payload (not a refinement, not the empty gripper), a change of the drive
   friction under the model in use -- per joint a factor on the viscous and
   on the Coulomb friction
   (:func:`identification.arm_payload.identify_arm_friction_change`) -- and,
   on a flexible prior, a change of the joints' springs -- per joint a factor
   on the stiffness and on the damping
   (:func:`identification.arm_payload.identify_arm_drive_change`; a gearbox
   that wears or warms) -- are fitted on the same window, and when one
   explains the window better than the payload by Vuong's test for
   non-nested models of the same data
   (:func:`ctc.adaptive.vuong_residual_statistic`, ``z`` beyond the normal
   quantile of ``false_alarm`` shared among the rivals, Bonferroni, as on
   the PUMA path; Q. H. Vuong, Econometrica 57, 1989) the decision is that
   rival's, ``'friction'`` or ``'drive'`` (``cause`` of the report); once a
   window of the episode has said so, the payload must explain each window
   significantly better than that rival (``z`` below minus that quantile)
   until a window shows no change.  And on a flexible prior with the empty
   gripper in use, an update whose estimate a rival explains better at all
   (``z`` > 0), if not significantly, waits for
   :data:`ARM_PERSISTENCE_WINDOWS` agreeing estimates (decision ``'held'``,
   the rivals ahead in the record's ``held_for``; the PUMA path's rule,
   :mod:`ctc.adaptive` step 5): one window of a softened spring reads as a
   payload.  The agreeing estimates then install, whatever the rivals say of
   them.  Measured on
   ``benchmarks/bench_arm_adaptive.py --compliant --kinds stiffness,damping``
   (``docs/figures/bench_arm_adaptive_drive_changes_20261381.txt``): see
   :doc:`tutorial_your_robot`.  Motor-side
   viscous friction reflected through a 100:1 gearbox can dominate a small
   arm's dynamics; measured on ``benchmarks/bench_arm_adaptive.py`` (seed
   20261301, planar draw 20261310) a 0.2 % friction change moved the
   replay by thousands of pulses^2 and one window read it as a 2.14 kg
   payload that fitted within the quantisation floors, and the update
   tracked worse than the static CTC (5 / 2 against 2 / 1 pulses).  None of
   these updates the model; the second
   window in a row that says so is reported (an event ``'unexplained'``
   with its ``cause`` and an :class:`ctc.adaptive.UnmodelledChangeWarning`,
   once per episode), and from then on only
   :data:`ARM_PERSISTENCE_WINDOWS` successive agreeing estimates (one
   payload: within 25 % + 50 g) update, and they install their estimates
   pooled by information (as a refinement's, step 4), not the last alone.
   **A return to the empty gripper is not held**: with a payload in use, a
   significant estimate within :data:`REFINEMENT_KG` of none installs the
   prior itself -- the static CTC's model, the reference the adaptive CTC
   must not fall behind -- from its one window, whatever the caution (not
   when a rollback rejected that return, step 4), and whether or not it
   describes its window: the window rejects the payload in use for none,
   and what the static CTC runs needs no description of it (an
   undescribed window -- a friction change, a collision -- whose fit
   lies at the empty gripper can so cost a carried tool its model, never
   the static CTC's tracking; the next windows identify the tool again;
   an undescribed window whose return a rollback rejected is
   unexplained).  The return is an
   update (on probation when it moves the model by more than a refinement
   would), it is fitted against no rival (the prior is what the static CTC
   runs), and it ends no episode of caution: a payload after it still
   needs agreeing estimates.
   Measured on ``benchmarks/bench_arm_adaptive.py --compliant --kinds
   pick-up,put-down --n 3 0 --seed 20262101``, planar draw 20262103 (a
   3.46 kg tool put down at 0.71 s), the version before held the first
   window after the put-down that an estimate described (the windows before
   it, whose springs rang beyond the start box of that version,
   :mod:`identification.arm_payload`, were unexplained) for a caution set
   before the put-down, and the 3.46 kg model ran the empty arm for a
   second: 19 / 12 pulses against the static CTC's 1 / 1
   (:doc:`tutorial_your_robot`).  On seed 20261861, planar draw 20261863
   (a 2.32 kg tool put down at 1.58 s), the first window after the
   put-down rejected the 2.32 kg model (36 million pulses^2) for 0.02 kg,
   which left 1254 pulses^2, beyond its limit of 33 (the springs rang);
   when a return had to describe its window, that one was unexplained,
   the next held for a caution, and the tool's model ran the empty arm
   until 2.3 s: 15 / 20 pulses against the static CTC's 1 / 1
   (``docs/figures/bench_arm_adaptive_compliant_payload_20261863_at_84efcc3.json``);
   returning on it, the prior takes effect at 1.9 s and the arm tracks
   1 / 1 (``..._payload_20261861.json``).
   A window that spans a pick-up or a put-down is half old robot, half
   new, and no payload describes it: its second half (at least 20 samples)
   is fitted again, and when a payload describes that half significantly
   the decision is taken on it (``half_window`` in the window's record;
   seed 20261301, planar draw 20261302: a put-down's update came 0.2 s
   earlier, 1 / 5 pulses after it became 1 / 1).
   **The second opinion**: with a payload in use, one window whose
   estimate of another payload (not a refinement, not the empty gripper)
   knows the mass less well than the model in use does -- a standard error
   above the pooled one of the estimates the model rests on, or none (the
   rule is off while the model's own is unknown) -- does not replace it:
   it is held (decision ``'held'``, the record's ``second_opinion``) until
   :data:`ARM_PERSISTENCE_WINDOWS` successive estimates agree, and those
   install pooled by information; a next window that knows more than the
   model installs alone, as any estimate that knows more replaces the
   model at once (a pick-up's first model, fitted on a window the pick-up
   spans, corrected by a sharper one).  The standard errors are the output
   error's at the quantisation floor and do not count a window's misfit of
   its start (links ringing beyond the start box): the false updates the
   compliant benchmark scores were such windows, under a model of the tool
   they carried, reading it 11--34 % heavier with standard errors of
   0.13--0.23 kg against the model's 0.002--0.025 (planar draws 20261892,
   20261863, 20261842; :doc:`tutorial_your_robot`).  A model rests on the
   window that brought it in -- the change's own, the most excited -- and
   on its refinements, so it is nearly always better known than one later
   window: a tool swapped for another with no empty gripper between waits
   one window more
   (``test_a_tool_swap_waits_for_a_second_opinion_unless_its_window_knows_more``).
4. **Rollback.**  The first whole window after an update to another
   payload is a probation: when its mean squared tracking error exceeds
   ``explain_factor`` times that of the window that triggered the update
   (and one pulse^2), the update made the arm track worse and the
   controller returns to the model it replaced (event ``'rollback'``);
   again only agreeing estimates update after that (but a return to the
   empty gripper, step 3), and none of the payload the rollback rejected
   (one payload: within 25 % + 50 g) until a window shows no change (the
   model in use describes the robot: an episode of caution ends there).  A
   window that shows a change no payload describes (one spanning a pick-up
   or a put-down) does not judge: its tracking answers that change, and the
   next window judges.  **The divergence guard** (the PUMA path's): two
   whole windows under one payload model, the second tracking worse than the
   first, than the window that brought the model in and than
   :data:`ctc.adaptive.DIVERGE_FACTOR` times the largest mean square of a
   window without change on the prior (and one pulse^2), return to the
   prior -- the static CTC's model -- at once, before the window is fitted
   (decision ``'diverging'``, an event ``'rollback'``; caution as after a
   rollback).  A heavier link model can take a flexible-joint CTC past its
   margins slowly, after its first window passed the probation: on the
   compliant benchmark's planar draw 20261926 (a 2.23 kg pick-up, seed
   20261921) the right 2.26 kg model ran the window mean squares up from
   1.4 to 1320 pulses^2 over a second, 118 / 86 pulses against the static
   CTC's 12 / 13 (:doc:`tutorial_your_robot`).
   A refinement -- an estimate within :data:`REFINEMENT_KG` + 5 % of the
   payload in use, significant against it -- installs every estimate of
   that payload since its update pooled by their information (the
   inverse variances of the mass; the base parameters, linear in the point
   mass's standard parameters, and the centre of mass by the same
   weights), moves the model little and is on no probation (measured on
   ``benchmarks/bench_arm_adaptive.py``, seed 20261201, planar draw 20261206: a refinement of a 4.97 kg tool
   judged by the window spanning its put-down was rolled back, and the
   caution that follows a rollback delayed the put-down's update by one
   window, 17 / 5 pulses against the static CTC's 1 / 1).  **Windows the
   model describes refine it too** (the quiet refinement, as on the PUMA
   path, ``_quiet_refinement``): a window whose likelihood ratio says
   "no change" still has its estimate, and while a payload is in use each
   such estimate that explains its window, lies inside the box and has a
   standard error is a measurement of it.  Once :data:`QUIET_WINDOWS` of
   them (within 25 % + 50 g of the model's mass) have come in since the
   model took effect, they are pooled with the model's own estimate by
   their information, and when the model's mass lies outside the
   combination's confidence interval at ``false_alarm`` (Wald's ``q = (m -
   m_comb)^2 / sd_comb^2`` beyond the chi-square quantile with one degree
   of freedom: for a right model at most that while the windows know no
   more than it) the combination is installed (decision
   ``'refinement'``, no probation, the record's ``quiet_wald``; on a
   flexible prior a heavier combination passes the switch check first;
   not after a change no payload explains was reported).  A model within
   +-1 pulse shows in no window's likelihood ratio, and one window's mass
   at a pick-up can be off by what its centre of mass takes up.  With the empty
   gripper in use there is nothing to refine: an estimate within
   :data:`REFINEMENT_KG` of it is the model in use (decision ``'not
   material'``, no event; the compliant benchmark's PUMA 560 joints 1--3
   draw 20262001, unchanged, had installed a 0.0002 kg "refinement").
5. **Repeatable.**  A model takes effect ``latency_s`` after its window's
   last sample: a fixed value (default :data:`DEFAULT_ARM_LATENCY_S`, the
   simulation's: two runs are identical bit for bit) or ``"measured"``
   (the wall time of the identification, for hardware).  While a model is
   pending no other window is identified.  The kernels are compiled when
   the controller is built (one identification of the prior's log).
6. **After a fallback.**  When the inner controller's watchdog hands the
   arm to the P law, no model is installed any more, but the windows go on
   being fitted -- the replay of the applied currents needs no model of the
   controller -- to say what changed (:mod:`ctc.adaptive`, step 6, on the
   PUMA path): two successive windows that agree name a friction change
   (the rival ahead of the payload, event ``'unexplained'``), a payload
   (a significant estimate inside the box that describes the window, the
   rival trailing it; event ``'diagnosis'``), or a change neither
   describes (``'unexplained'``, ``cause='unknown'``).

**A flexible prior** (an arm identified with two-mass joints,
``model == "flexible"``) gets the inner controller of
:meth:`ctc.arm.ArmComputedTorque.from_result`: the robust flexible-joint
design (:class:`ctc.arm.ArmFlexibleComputedTorque`), or the
rigid-equivalent CTC when no flexible design holds the model-error set
(its warning is kept in ``design_warnings``).  Each window's payload is
identified through the prior's two-mass arm
(:func:`identification.arm_payload.identify_arm_payload`: the springs,
dampers, motor inertias and backlash held, the links' start state the
springs' quasi-static deflection under the loaded link plus refined
offsets), and so are the friction rival and the springs' rival (step 3:
a change of their stiffness and damping); an update switches the
controller's rigid-equivalent model, whose link model and link-observer
gains follow (:meth:`ctc.arm.ArmFlexibleComputedTorque.set_beta`).  The
PUMA path does the same (:class:`ctc.adaptive.AdaptiveComputedTorqueController`
on a flexible prior).

**The switch check** (flexible priors).  The inner controller's design was
checked on the identified arm as it was (its model-error set: stiffness
+-30 %, damping x0.5-2), not carrying a payload, and a computed torque
multiplies its feedback by the model's inertia: a heavier model raises
the loop gain at the springs' modes.  Measured on
``benchmarks/bench_arm_adaptive.py --compliant`` (seed 20261901, planar
draw 20261902, a soft second joint, the rigid-equivalent CTC chosen): the
right 4.22 kg installed at 1.9 s drove the arm from 17 / 62 to 6521 / 760
pulses within 0.09 s, past the watchdog, and the P law could not hold the
loaded arm either.  So before an update to another payload takes effect,
a copy of the inner controller with the new model runs on the prior's
two-mass arm carrying that payload along the first
:data:`ctc.arm.FLEXIBLE_CHECK_S` seconds of the reference (the design
check's simulation), and the update is made when its error after
0.1 s stays within :data:`SWITCH_MARGIN_PULSES` of the worst case the
design check accepted (at least :data:`ctc.arm.GOAL_PULSES`). Otherwise
the model in use, kept on that arm, is checked beside it: the update is
still made when it tracks there at least :data:`SWITCH_GAIN_PULSES`
better than the model in use (the alternative to the switch; its reason
says so) and has not lost that arm (every joint within
:func:`ctc.guard.lost_bound` of the log, the bound beyond which the
design check counts a run as lost). If neither, the model is kept
(decision ``'unsafe'``, an event ``'unsafe'`` and a ``RuntimeWarning``
once per payload): the controller says that it cannot carry the payload
it found, rather than carry it unstably. A later estimate of the same
payload (within 25 % + 50 g) is refused without another check. Rigid
priors skip the check (a rigid arm's CTC with its right model is the
design).

**Held feedback** (a flexible prior whose design is the rigid-equivalent
CTC, ``held_feedback``). That CTC's gains and observer were checked with
the design model's inertia multiplying its feedback; a payload's model
enters its feed-forward only, the feedback held at the design's model
(:meth:`ctc.arm.ArmComputedTorque.set_beta` with ``feedback_beta``,
:mod:`ctc.arm`): the map from the counts to the feedback current stays
the checked one. Measured on
``benchmarks/bench_arm_adaptive.py --compliant`` (seed 20261831, planar
draw 20261835, a 2.07 kg pick-up):
given the right 2.09 kg model with its own inertia on the feedback, the
CTC diverged on the identified two-mass arm carrying the tool, and the
check refused every window (the arm tracked as the static CTC, 37 / 16
pulses; ``docs/figures/bench_arm_adaptive_compliant_20261831.json``);
with the feedback held it tracks that arm within 36 pulses against the
model in use's 50, the update is made, and the arm of the independent
simulator tracks 4 / 2 pulses from 0.5 s after the pick-up (before it,
the same CTC tracked 6 / 1; ``..._20261831_held_feedback.json``).

**The hand-over** (a flexible-joint inner CTC, ``hands_over``).  That
CTC feeds forward the spring torque of a link model driven by the motor's
path, its link estimate corrected only slowly by the motor observer's
residual (:class:`ctc.arm.ArmFlexibleComputedTorque`).  Before an update
that estimate ran the old model: with a tool the model lacked, the links
sagged and rang where it did not, and on the new model it starts from
there.  So when an update to another payload (not a refinement) takes
effect, the window's fit -- the output-error replay of the arm identified
on it (the window's estimate, which the installed model, pooled over
windows or the prior itself, need not be) from its fitted start state,
the links' ringing included -- is continued
through the run's logged errors and commands to the present sample
(:func:`identification.arm_payload.replay_arm_state`), and its link state
becomes the controller's link estimate
(:meth:`ctc.arm.ArmFlexibleComputedTorque.set_link_estimate`; a bumpless
transfer from a state estimate: L. Zaccarian and A. R. Teel, Automatica
41, 2005); not when the window's estimate does not describe it (the fit's
state is then no estimate of the arm), nor on a rollback.  The replay
runs in the sample the model takes effect (one replay of the window and
the latency: on hardware, a longer computation in that sample).  The
record is ``handovers``.  Measured on ``benchmarks/bench_arm_adaptive.py
--compliant`` (seed 20261871, planar draw 20261873, a 4.20 kg pick-up at
1.42 s), the right 4.21 kg model took effect at 1.9 s on the old model's
link estimate, and from 0.5 s after the pick-up the arm tracked 57 / 51
pulses, worse than the static CTC's 41 / 33
(``docs/figures/bench_arm_adaptive_compliant_20261871.json``); handed
over, the estimate moves by 117 / 402 pulses at 1.9 s and the arm tracks
2 / 3 pulses (``..._20261873_handover.json``).

The controller follows the sampled-controller protocol (``reset()``,
``__call__(k, t, q_meas, e_pulses) -> (n,) A``), so
:func:`plant.simulate_closed_loop` (``plant=`` the arm) and the
independent simulator of ``benchmarks/`` run it.
"""
from __future__ import annotations

import dataclasses
import math
import time
import warnings

import numpy as np

from .adaptive import (DEFAULT_LATENCY_S, DIVERGE_FACTOR, PERSISTENCE_WINDOWS,
                       UnmodelledChangeWarning, residual_statistics, same_payload,
                       vuong_residual_statistic)
from .arm import ArmComputedTorque, ArmFlexibleComputedTorque, log_envelope
from .guard import lost_bound

__all__ = ["ArmAdaptiveComputedTorque", "DEFAULT_ARM_LATENCY_S", "DEFAULT_ARM_WINDOW_S",
           "ARM_PERSISTENCE_WINDOWS", "QUIET_WINDOWS", "REFINEMENT_KG",
           "SWITCH_MARGIN_PULSES", "SWITCH_GAIN_PULSES"]

#: Default window (s): the paper's 100-200 ms, its upper end (a window of an n-joint arm
#: determines the mass and the first moment of a point mass on the last link;
#: ``benchmarks/bench_arm_payload.py``).
DEFAULT_ARM_WINDOW_S = 0.2

#: Default latency (s) of a window's model: the PUMA path's (:data:`ctc.adaptive.DEFAULT_LATENCY_S`).
DEFAULT_ARM_LATENCY_S = DEFAULT_LATENCY_S

#: Successive agreeing estimates that update after a rollback or an unexplained change.
ARM_PERSISTENCE_WINDOWS = 2

#: Estimates of windows the model in use describes that the quiet refinement pools with
#: the model (step 4): the PUMA path's :data:`ctc.adaptive.PERSISTENCE_WINDOWS`.
QUIET_WINDOWS = PERSISTENCE_WINDOWS


#: The switch check's tolerance (flexible priors, module docstring): an update's model may
#: track the loaded identified arm this many pulses worse than the design check's worst case.
SWITCH_MARGIN_PULSES = 1.0

#: ... or track it at least this many pulses better than the model in use does there
#: (the alternative to the switch: the model kept on the arm carrying the payload).
SWITCH_GAIN_PULSES = 1.0


#: A new estimate whose mass is within this many kg (plus 5 %) of the payload in use
#: refines it: installed without probation (step 4).
REFINEMENT_KG = 0.05


def _pooled(entries):
    """Estimates ``(mass, mass std, beta, com)`` pooled by their information.

    Parameters
    ----------
    entries : list of tuple
        Each ``(m, sd, beta, com)``: the mass (kg), its standard error (kg, NaN when
        unknown), the loaded arm's base parameters ``(p,)`` and the centre of mass
        ``(3,)`` (m, last link's frame).

    Returns
    -------
    beta : ndarray, shape (p,)
    mass_kg : float
    com_m : ndarray, shape (3,)
        The weighted means, weights ``1 / sd**2`` (equal weights when a standard error is
        unknown): the base parameters are linear in the point mass's standard parameters,
        so the pooled ``beta`` is the pooled payload's (for the centre of mass as a
        first-moment mean, to first order).
    mass_std : float
        The pooled mass's standard error, ``(sum 1 / sd**2)**-1/2`` (kg; NaN when a
        standard error is unknown).
    """
    sds = np.array([q[1] for q in entries], dtype=float)
    known = bool(np.all(np.isfinite(sds)) and np.all(sds > 0))
    w = 1.0 / sds ** 2 if known else np.ones(len(entries))
    sd = float(1.0 / math.sqrt(w.sum())) if known else math.nan
    w = w / w.sum()
    beta = np.sum([wi * np.asarray(q[2], dtype=float) for wi, q in zip(w, entries)], axis=0)
    m = float(np.dot(w, [q[0] for q in entries]))
    com = np.sum([wi * np.asarray(q[3], dtype=float) for wi, q in zip(w, entries)], axis=0)
    return beta, m, com, sd


def _refines(a, b) -> bool:
    """Mass ``a`` (kg) refines the payload in use of mass ``b``."""
    return abs(a - b) <= 0.05 * max(abs(a), abs(b)) + REFINEMENT_KG


class ArmAdaptiveComputedTorque:
    """Computed-torque control of an arm whose payload is identified on-line (module docstring).

    Parameters
    ----------
    prior : identification.arm.ArmIdentificationResult
        The unloaded arm, identified rigid or flexible (its plant, base
        parameters and rig, with the identified friction when the sidecar
        had none; a flexible result also its joints, ``plant_row``).
    log : plant.logs.arm_log.ArmLog
        The log the prior was identified from (rig, reference; its first
        window compiles the kernels).
    window_s : float
        Length of each identified window (s), at least 20 samples.
    latency_s : float or "measured"
        Delay from a window's last sample to its model taking effect (s):
        fixed (repeatable) or the identification's wall time.
    false_alarm : float
        Probability that a window of an unchanged arm passes the significance
        test (0 < false_alarm < 1).
    explain_factor : float
        Rollback threshold (> 1) on the first window after an update.
    bounds : array_like, shape (4, 2), optional
        Box of ``[m, cx, cy, cz]`` (default
        :data:`identification.arm_payload.DEFAULT_ARM_PAYLOAD_BOUNDS`).
    trajectory : plant.Trajectory, optional
        The reference to track (default the log's).
    envelope : array_like, shape (n,) or None or "log"
        The inner controller's following-error limit (pulses); ``"log"``
        (default): :func:`ctc.arm.log_envelope`, twice the log's largest
        P-control errors.
    **design
        Gains of the inner controller (:class:`ctc.arm.ArmComputedTorque`; of
        a flexible prior's also ``max_current_per_pulse``, as
        :meth:`ctc.arm.ArmComputedTorque.from_result`).

    Attributes
    ----------
    flexible : bool
        The prior is a two-mass arm (module docstring).
    rivals : tuple of str
        The changes an update is tested against (step 3): ``('friction',)``, and
        ``('friction', 'drive')`` on a flexible prior.
    design_warnings : list of str
        A flexible prior's design warnings (e.g. the rigid-equivalent CTC
        kept because no flexible design holds the model-error set).
    held_feedback : bool
        A flexible prior whose inner controller is the rigid-equivalent CTC:
        a payload's model enters its feed-forward, the feedback held at the
        design's model (module docstring).
    hands_over : bool
        The inner controller is the flexible-joint CTC: an update to another
        payload whose estimate describes its window hands it the link
        estimate of that window's replay (module docstring, the hand-over).
    handovers : list of dict
        Per hand-over: ``t_s`` (the sample the model took effect), ``from_s``
        (the replay's first sample, the fitted window's) and
        ``link_shift_pulses`` (n,), how far the link estimate moved (joint
        angle times the encoder's pulses per radian), or ``message`` when the
        replay failed and the estimate stayed.
    beta : ndarray, shape (r,)
        The base parameters in use.
    payload : dict or None
        The payload in use (``mass_kg``, ``com_m``) or None.
    payload_history : list of (float, float)
        ``(t_s, mass_kg)`` each time a model took effect, starting with
        ``(0.0, 0.0)``.
    events : list of dict
        ``t_s``, ``kind`` (``'update'``, ``'refinement'``, ``'rollback'``,
        ``'unexplained'``, ``'unsafe'``, ``'diagnosis'``) and ``message``;
        a reported change adds its ``cause`` (``'friction'``, ``'drive'``, ``'unknown'``;
        ``'payload'`` for a diagnosis, with its ``payload``).
    diagnosis : str or None
        What the windows after the watchdog's fallback named (module
        docstring): ``'friction'``, ``'payload'``, ``'unknown'``, or None.
    diagnoses : list of dict
        Per window after the fallback: ``window_s``, ``said`` (what the
        window alone says, or None), ``named``, and the fits' ``mass_kg``,
        ``lr``, ``threshold``, ``y_now``, ``y_new``, ``limit``,
        ``friction_z``, ``friction_y``, ``friction_factors``, ``elapsed_s``
        (or ``error`` when a fit failed).
    identifications : list of dict
        Per identified window: ``window_s``, ``decision`` (``'no change'``,
        ``'update'``, ``'refinement'``, ``'not material'`` (a significant
        estimate within :data:`REFINEMENT_KG` of the empty gripper in use),
        ``'held'``, ``'implausible'``,
        ``'unexplained'``, ``'friction'``, ``'drive'``, ``'unsafe'``, ``'failed'``,
        ``'diverging'`` (the divergence guard, step 4: no fit, NaN estimates); a
        flexible prior's switch check adds ``switch_check_pulses`` and
        ``switch_check_bound`` (beyond it, the model in use's
        ``switch_check_kept_pulses``, and for an update made on it
        ``switch_note``); a fitted friction
        rival adds ``friction_z``, ``friction_y`` and ``friction_factors``, a fitted
        springs' rival ``drive_z``, ``drive_y`` and ``drive_factors``), ``mass_kg``,
        ``mass_std``, ``lr``, ``threshold``,
        ``y_now``, ``y_new`` (pulses^2), ``tracking_mse`` (pulses^2),
        ``elapsed_s``, ``reason`` and, when the decision was taken on the
        second half of a window spanning a change, ``half_window``; a window the
        payload in use was tested by the quiet refinement, ``quiet_wald`` (step 4);
        a window held because a rival explained its estimate (or the one that began
        the wait) better, ``held_for`` (the rivals, step 3).

    Raises
    ------
    ValueError
        A prior that is not a successful arm identification (a flexible one
        without its joints), a window
        shorter than 20 samples, a latency that is neither >= 0 nor
        ``"measured"``, ``false_alarm`` outside (0, 1), ``explain_factor`` <= 1,
        or any error of :class:`ctc.arm.ArmComputedTorque`.
    """

    def __init__(self, prior, log, *, window_s=DEFAULT_ARM_WINDOW_S,
                 latency_s=DEFAULT_ARM_LATENCY_S, false_alarm=1e-3, explain_factor=4.0,
                 bounds=None, trajectory=None, envelope="log", **design):
        from scipy.stats import chi2, norm

        from identification.arm_payload import (DEFAULT_ARM_PAYLOAD_BOUNDS,
                                                identify_arm_drive_change,
                                                identify_arm_friction_change,
                                                identify_arm_payload)

        if not (hasattr(prior, "get") and prior.get("plant") is not None
                and prior.get("beta") is not None):
            raise ValueError("prior must be an identification.arm.identify_arm result")
        self.flexible = prior.get("model", "rigid") != "rigid"
        if self.flexible and prior.get("plant_row") is None:
            raise ValueError("a flexible prior needs its two-mass arm's joints (plant_row of an "
                             "identification.arm.identify_arm result with model 'flexible')")
        if not prior.get("success", False):
            raise ValueError(f"the prior's identification did not succeed: {prior.get('message')}")
        self.prior = prior
        self.log = log
        self.trajectory = log.trajectory if trajectory is None else trajectory
        ts = float(log.rig.sample_time_s)
        self.ts = ts
        self.window_n = int(round(float(window_s) / ts))
        if self.window_n < 20:
            raise ValueError(f"window_s={window_s} gives {self.window_n} samples; at least 20 "
                             "are needed")
        self.window_s = self.window_n * ts
        if isinstance(latency_s, str):
            if latency_s != "measured":
                raise ValueError(f"latency_s must be a number >= 0 or 'measured', got {latency_s!r}")
        elif not (np.isfinite(latency_s) and latency_s >= 0):
            raise ValueError(f"latency_s must be a number >= 0 or 'measured', got {latency_s!r}")
        self.latency_s = latency_s
        if not 0.0 < float(false_alarm) < 1.0:
            raise ValueError(f"false_alarm must be in (0, 1), got {false_alarm!r}")
        self.false_alarm = float(false_alarm)
        if not float(explain_factor) > 1.0:
            raise ValueError(f"explain_factor must be > 1, got {explain_factor!r}")
        self.explain_factor = float(explain_factor)
        self.bounds = np.asarray(DEFAULT_ARM_PAYLOAD_BOUNDS if bounds is None else bounds,
                                 dtype=float)
        self._chi2 = chi2
        if isinstance(envelope, str):
            if envelope != "log":
                raise ValueError(f"envelope must be n pulses, None or 'log', got {envelope!r}")
            envelope = log_envelope(log)
        self.prior_beta = np.asarray(prior["beta"], dtype=float).copy()
        self.design_warnings = []
        if self.flexible:
            # the robust flexible-joint design of the prior (ctc.arm.ArmComputedTorque.from_result:
            # the flexible-joint CTC, or the rigid-equivalent one when no flexible design holds
            # the model-error set), for the reference to be tracked
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                self._ctc = ArmComputedTorque.from_result(
                    prior, dataclasses.replace(log, trajectory=self.trajectory),
                    envelope=envelope, **design)
            for w in caught:
                self.design_warnings.append(str(w.message))
                warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
        else:
            self._ctc = ArmComputedTorque(prior["plant"], self.prior_beta, prior["rig"],
                                          self.trajectory, envelope=envelope, **design)
        self.n = self._ctc.n
        # a flexible prior's rigid-equivalent CTC holds its feedback at the design's model
        # (ctc.arm, held feedback): a payload's model adds its feed-forward only
        self.held_feedback = self.flexible and not isinstance(self._ctc, ArmFlexibleComputedTorque)
        # a flexible-joint inner CTC takes each update's link estimate from the window's replay
        self.hands_over = isinstance(self._ctc, ArmFlexibleComputedTorque)
        self._design_beta = self._ctc.beta.copy()
        self._identify_payload = identify_arm_payload
        self._identify_friction = identify_arm_friction_change
        self._identify_drive = identify_arm_drive_change
        self._z_threshold = float(norm.isf(self.false_alarm))
        # the rivals of an update (step 3): the drive friction, and on a flexible prior the
        # joints' springs; a rival stops an update at false_alarm shared among them
        # (Bonferroni), as on the PUMA path
        self.rivals = ("friction", "drive") if self.flexible else ("friction",)
        self._rival_z = float(norm.isf(self.false_alarm / len(self.rivals)))
        # compile the replay kernels now, not inside the loop: one window of the prior's log,
        # the payload's and the rivals'
        k1 = min(log.n_samples, max(self.window_n, 20))
        first = (0.0, (k1 - 1) * ts)
        identify_arm_payload(log, prior, window_s=first, bounds=self.bounds, workers=1, max_iter=2)
        identify_arm_friction_change(log, prior, window_s=first, currents=None, workers=1,
                                     max_iter=2)
        if self.flexible:
            identify_arm_drive_change(log, prior, window_s=first, currents=None, workers=1,
                                      max_iter=2)
        self.reset()

    @classmethod
    def from_result(cls, prior, log, **options):
        """The adaptive controller of an unloaded arm's identification on its log's rig.

        Parameters
        ----------
        prior : identification.arm.ArmIdentificationResult
        log : plant.logs.arm_log.ArmLog
        **options
            Keywords of the constructor (``window_s``, ``latency_s``,
            ``trajectory``, gains, ...).

        Returns
        -------
        ArmAdaptiveComputedTorque

        Raises
        ------
        ValueError
            As the constructor.
        """
        return cls(prior, log, **options)

    # ------------------------------------------------------------------ protocol
    def reset(self) -> None:
        """Back to the prior; forget the run, the history and any pending model."""
        self._ctc.reset()
        self._install(self.prior_beta, None)
        self.payload_history = [(0.0, 0.0)]
        self.events = []
        self.identifications = []
        self._E = np.zeros((0, self.n), dtype=np.int64)
        self._I = np.zeros((0, self.n))
        self._pending = None  # (k_effective, beta, payload, trigger_mse, quiet, start)
        self._rejected = None  # the mass (kg) a rollback rejected, until a window shows no change
        self._probation = None  # (k_from, trigger_mse, previous beta, previous payload)
        self._cautious = False  # after a rollback or an unexplained change: agreeing estimates
        self._held_for = []  # the rivals ahead of a held update's estimate (step 3), if that began it
        self._agree = []  # the latest successive significant estimates (m, sd, beta, com)
        self._pool = []  # estimates of the payload in use since its update (m, sd, beta, com)
        self._since = []  # estimates of windows the model in use describes, since it took effect
        self._odd = 0  # successive windows a payload does not describe
        self._causes = []  # their causes ('friction', 'drive', 'unknown')
        self._named = set()  # the rival changes reported in this episode ('friction', 'drive')
        self._warned = False
        self._unsafe = []  # payloads (kg) the switch check refused (flexible priors)
        self.handovers = []
        self.diagnosis = None
        self.diagnoses = []
        self._mse_normal = None  # largest tracking mean square of a no-change window on the prior
        self._trigger_mse = None  # that of the window that brought the model in use in
        self._last_window = None  # (time the model took effect, mse) of the last whole window

    def __call__(self, k, t, q_meas, e_pulses) -> np.ndarray:
        """Motor currents (n,) A for sample ``k`` (sampled-controller protocol)."""
        if k >= self._E.shape[0]:
            grow = max(k + 1, 2 * self._E.shape[0], 1024)
            self._E = np.vstack([self._E, np.zeros((grow - self._E.shape[0], self.n), np.int64)])
            self._I = np.vstack([self._I, np.zeros((grow - self._I.shape[0], self.n))])
        self._E[k] = np.asarray(e_pulses, dtype=np.int64)
        if self._pending is not None and k >= self._pending[0]:
            k_eff, beta, payload, trigger, quiet, start = self._pending
            self._pending = None
            m_new = 0.0 if payload is None else payload["mass_kg"]
            # a refinement of the payload in use (its mass within REFINEMENT_KG + 5 %, or the
            # quiet refinement's combination) moves the model little and is on no probation
            # (one on trial stays); another payload is
            moves = not quiet and not _refines(m_new, self.payload_mass_kg)
            if moves:
                self._probation = (k_eff, trigger, self.beta, self.payload)
            self._trigger_mse = trigger  # the window that brought the model in (the guard)
            self._install(beta, payload)
            if moves and start is not None and self.hands_over:
                self._hand_over(k, start)
            self.payload_history.append((k * self.ts, self.payload_mass_kg))
            self._since = []  # the quiet refinement tests the model on windows it has run
        i = np.asarray(self._ctc(k, t, q_meas, e_pulses), dtype=float)
        self._I[k] = i  # the inner controller's command is within full scale already
        k1 = k + 1
        if k1 % self.window_n == 0 and self._pending is None:
            if self._ctc.fallback_t_s is None:
                self._identify(k1)
            elif self.diagnosis is None:
                self._diagnose(k1)
        return i

    # ------------------------------------------------------------------ internals
    def _install(self, beta, payload) -> None:
        self.beta = np.asarray(beta, dtype=float).copy()
        self.payload = payload
        self._ctc.set_beta(self.beta, feedback_beta=self._feedback_for(self.beta))

    def _hand_over(self, k, start) -> None:
        """The link estimate at sample ``k``: the window's fit ``start = (t_s, state, beta)``
        (its first sample, its start state, the base parameters it was fitted with) continued
        through the run's logged errors and commands (module docstring, hand-over)."""
        from identification.arm_payload import replay_arm_state

        t0, x0, beta = start
        n = self.n
        before = self._ctc.link_estimate()
        rec = dict(t_s=k * self.ts, from_s=float(t0))
        try:
            x = replay_arm_state(self._window_log(k + 1), self.prior, beta, x0, (t0, k * self.ts))
        except ValueError as err:  # a window the replay cannot take: the estimate stays
            x, rec["message"] = None, str(err)
        if x is not None and np.all(np.isfinite(x)):
            self._ctc.set_link_estimate(x[:n], x[n:2 * n])
            rec["link_shift_pulses"] = ((x[:n] - before[:n]) * self._ctc.spr).tolist()
        else:
            rec.setdefault("message", "the replay failed: the link estimate stays")
        self.handovers.append(rec)

    def _feedback_for(self, beta):
        """The model the inner CTC holds its feedback at with ``beta`` in use (None: its own)."""
        if self.held_feedback and not np.array_equal(beta, self._design_beta):
            return self._design_beta
        return None

    def _event(self, k, kind, message, **details) -> None:
        self.events.append(dict(t_s=k * self.ts, kind=kind, message=message, **details))

    def _window_log(self, k1):
        """The run so far as an arm log (the controller's commands as ``i_A``)."""
        t = np.arange(k1) * self.ts
        q_ref = np.asarray(self.trajectory.position(t), dtype=float).reshape(k1, self.n)
        return dataclasses.replace(self.log, t=t, q_ref=q_ref, e_pulses=self._E[:k1].copy(),
                                   i_A=self._I[:k1].copy(), trajectory=self.trajectory,
                                   rig=self.prior["rig"])

    def _pinned(self, payload) -> np.ndarray:
        """A box that pins the payload ``payload`` (None: no payload) for the null fit."""
        m, c = (0.0, np.zeros(3)) if payload is None else (payload["mass_kg"], payload["com_m"])
        x = np.concatenate([[m], np.asarray(c, dtype=float)])
        return np.column_stack([x, x + 1e-9])

    def _fit_window(self, wlog, k0, k1) -> dict:
        """The payload estimate and the model in use fitted on samples ``k0 .. k1 - 1``, and
        their likelihood-ratio statistics (:func:`ctc.adaptive.residual_statistics`)."""
        from identification.flexible import INADEQUATE_FACTOR, quantisation_floor

        window = (k0 * self.ts, (k1 - 1) * self.ts)
        est = self._identify_payload(wlog, self.prior, window_s=window, currents="logged",
                                     bounds=self.bounds, workers=1)
        # the two fits on equal terms: the pinned one starts from the link box the free one
        # ended in, and the free one is fitted again when the pinned one had to widen it
        # (a two-mass arm's links ringing beyond the box, identification.arm_payload)
        link = est.get("link_box_pulses")
        now = self._identify_payload(wlog, self.prior, window_s=window, currents="logged",
                                     bounds=self._pinned(self.payload), workers=1,
                                     link_box_pulses=link)
        wider = now.get("link_box_pulses")
        if link is not None and wider is not None and np.any(wider > link):
            again = self._identify_payload(wlog, self.prior, window_s=window, currents="logged",
                                           bounds=self.bounds, workers=1, link_box_pulses=wider)
            if again.success and again.fun < est.fun:
                est = again
        dof = 1 + int(np.sum(est.com_identifiable))
        out = dict(window=window, est=est, now=now, ok=bool(est.success and now.success),
                   threshold=float(self._chi2.isf(self.false_alarm, dof)))
        if out["ok"]:
            st = residual_statistics(now.residuals_pulses, est.residuals_pulses, dof)
            floor = quantisation_floor(st["n_values"])
            out.update(st=st, floor=floor, limit=INADEQUATE_FACTOR * floor)
        return out

    def _identify(self, k1) -> None:
        """Identify the window ending before sample ``k1`` and act on the decision."""
        k0 = k1 - self.window_n
        e = self._E[k0:k1].astype(float)
        mse = float(np.mean(e * e))
        if self._diverging(k0, k1, mse):
            return
        t_wall = time.perf_counter()
        wlog = self._window_log(k1)
        fit = self._fit_window(wlog, k0, k1)
        est, now = fit["est"], fit["now"]
        rec = dict(window_s=fit["window"], decision="failed", mass_kg=float(est.mass_kg),
                   mass_std=float(est.x_std[0]), lr=float("nan"), threshold=fit["threshold"],
                   y_now=float(now.fun), y_new=float(est.fun), tracking_mse=mse,
                   elapsed_s=0.0, reason="")
        self.identifications.append(rec)
        try:
            self._decide(wlog, k0, k1, fit, rec, mse)
        finally:
            rec["elapsed_s"] = time.perf_counter() - t_wall
        if self._pending is not None and self._pending[0] is None:
            # the update's latency: fixed, or the identification's wall time ('measured')
            latency = rec["elapsed_s"] if self.latency_s == "measured" else float(self.latency_s)
            k_eff = k1 + max(int(math.ceil(latency / self.ts - 1e-9)), 0)
            self._pending = (k_eff,) + self._pending[1:]
            kind = rec["decision"]
            m_new = 0.0 if self._pending[2] is None else self._pending[2]["mass_kg"]
            self._event(k_eff, kind, f"payload {m_new:.3g} kg ({rec['reason']})", mass_kg=m_new)

    def _decide(self, wlog, k0, k1, fit, rec, mse) -> None:
        """The supervisor's decision on one window (module docstring, steps 2-4)."""
        from identification.flexible import INADEQUATE_FACTOR

        if not fit["ok"]:
            est = fit["est"]
            rec["reason"] = est.message if not est.success else fit["now"].message
            self._agree = []  # agreeing estimates are successive windows'
            return
        st, limit = fit["st"], fit["limit"]
        rec["lr"] = float(st["lr"])
        # a window that shows a change no payload describes (one spanning a pick-up, a
        # put-down, a collision) does not judge the update on probation: its tracking
        # answers that change, not the update; the next window does
        if st["y_new"] <= limit:
            self._judge_probation(k0, k1, mse)
        half = self.window_n // 2
        if st["y_new"] > limit and half >= 20:
            # a window spanning a change: its second half may be the robot as it is now
            late = self._fit_window(wlog, k1 - half, k1)
            if late["ok"] and late["st"]["y_new"] <= late["limit"] \
                    and late["st"]["lr"] > late["threshold"]:
                fit = late
                st, limit = fit["st"], fit["limit"]
                rec.update(window_s=fit["window"], half_window=True, lr=float(st["lr"]),
                           threshold=fit["threshold"], mass_kg=float(fit["est"].mass_kg),
                           mass_std=float(fit["est"].x_std[0]), y_now=float(fit["now"].fun),
                           y_new=float(fit["est"].fun))
        est, threshold, floor = fit["est"], fit["threshold"], fit["floor"]
        window = fit["window"]
        m = float(est.mass_kg)
        payload = dict(mass_kg=m, com_m=np.asarray(est.com_m, dtype=float).copy())
        if st["lr"] <= threshold and st["y_now"] > limit and st["y_new"] > limit:
            # neither the model in use nor any payload describes the window: no test between
            # them, but a change (friction, damping, a collision, or a window spanning a change)
            rec.update(decision="unexplained",
                       reason=(f"neither the model in use ({st['y_now']:.4g} pulses^2) nor the "
                               f"best payload ({m:.3g} kg, {st['y_new']:.4g}) describes the "
                               f"window: more than {INADEQUATE_FACTOR:g} quantisation floors "
                               f"({floor:.4g})"))
            self._unexplained(k1, rec)
            return
        if st["lr"] <= threshold:
            # the model in use describes the window: an episode of caution is over
            rec.update(decision="no change", reason=f"LR {st['lr']:.3g} <= {threshold:.3g}")
            if self.payload is None and k0 * self.ts >= self.payload_history[-1][0] - 1e-12:
                # a whole window on the prior (not one a return to it took effect in)
                self._mse_normal = mse if self._mse_normal is None else max(self._mse_normal, mse)
            self._odd = 0
            self._causes = []
            self._agree = []
            self._cautious = False
            self._held_for = []
            self._rejected = None
            self._named = set()
            self._quiet_refinement(k1, fit, rec, mse)
            return
        if self._at_mass_bound(m):
            rec.update(decision="implausible", reason=f"mass {m:.3g} kg at the box's upper end")
            self._unexplained(k1, rec)
            return
        # a return to the empty gripper -- the prior, the static CTC's model -- is no payload
        # to doubt: caution holds payloads, not the model the static CTC runs on; nor need
        # its window be described: the payload in use rejected significantly for none is
        # reason enough to run what the static CTC runs (module docstring, step 3)
        to_prior = self.payload is not None and m <= REFINEMENT_KG
        rejected = self._rejected is not None and same_payload(m, self._rejected)
        if st["y_new"] > limit and not (to_prior and not rejected):
            rec.update(decision="unexplained",
                       reason=(f"the best payload ({m:.3g} kg) leaves {st['y_new']:.4g} pulses^2, "
                               f"more than {INADEQUATE_FACTOR:g} quantisation floors "
                               f"({floor:.4g})"))
            self._unexplained(k1, rec)
            return
        undescribed = st["y_new"] > limit
        if not _refines(m, self.payload_mass_kg) and m > REFINEMENT_KG:
            # the rivals (step 3): a change of the drive friction, and on a flexible prior of
            # the joints' springs, under the model in use
            rival = self._rival(wlog, window, est, m, st, rec)
            if rival is not None:
                rec.update(decision=rival[0], cause=rival[0], reason=rival[1])
                self._unexplained(k1, rec)
                return
            ahead = [c for c in self.rivals if rec.get(f"{c}_z", -math.inf) > 0.0]
            if ahead and self.flexible and self.payload is None and not self._cautious:
                # a rival ahead of the payload, if not significantly, on a flexible prior with
                # the empty gripper in use: one window is no reason to install a payload (a
                # spring that softens reads as one; module docstring, step 3) -- the update
                # waits for ARM_PERSISTENCE_WINDOWS agreeing estimates, as after a rollback
                self._cautious = True
                self._held_for = ahead
        self._odd = 0
        self._causes = []
        if self._rejected is not None and same_payload(m, self._rejected):
            rec.update(decision="held",
                       reason=f"{m:.3g} kg is the payload a rollback rejected "
                              f"({self._rejected:.3g} kg); held until a window shows no change")
            self._agree = []
            return
        sd = float(est.x_std[0])
        entry = (m, sd if np.isfinite(sd) and sd > 0 else math.nan,
                 np.asarray(est.beta, dtype=float), payload["com_m"])
        self._agree = (self._agree + [entry])[-ARM_PERSISTENCE_WINDOWS:]
        # the second opinion (step 3): one window whose estimate knows the payload less well
        # than the model in use does -- a larger standard error than the pooled one the model
        # rests on -- does not replace that payload by another; a put-down's return to the
        # prior and a refinement are not held
        sd0 = math.nan if self.payload is None else float(self.payload.get("mass_std", math.nan))
        less_known = (self.payload is not None and not to_prior
                      and not _refines(m, self.payload_mass_kg)
                      and np.isfinite(sd0) and sd0 > 0 and not entry[1] <= sd0)
        if less_known:
            rec["second_opinion"] = True
        confirm = self._cautious or less_known
        agreeing = sum(same_payload(a[0], m) for a in self._agree)
        if confirm and not to_prior and agreeing < ARM_PERSISTENCE_WINDOWS:
            if self._held_for and self._cautious:
                rec["held_for"] = list(self._held_for)
            if self._cautious:
                why = (" and ".join(f"the {c} rival" for c in self._held_for)
                       + " explained a window better than the payload, if not significantly"
                       if self._held_for else "a change no payload explained or a rollback")
            else:
                why = (f"one window's {m:.3g} +- {sd:.2g} kg, less known than the "
                       f"{self.payload_mass_kg:.3g} +- {sd0:.2g} kg in use")
            rec.update(decision="held",
                       reason=f"{agreeing} agreeing estimate(s) of "
                              f"{ARM_PERSISTENCE_WINDOWS} needed after {why}")
            return
        # the estimates this update rests on: the agreeing ones after a caution or for a
        # second opinion (each was held, none installed), else this window's
        agreed = self._agree if confirm else [entry]
        self._agree = []
        kind = "refinement" if _refines(m, self.payload_mass_kg) and not to_prior else "update"
        if kind == "refinement" and self.payload is None:
            # the empty gripper has no payload to refine: a mass within REFINEMENT_KG of it
            # is the model in use (a refinement installed 0.0002 kg on an unchanged arm)
            rec.update(decision="not material",
                       reason=f"{m:.3g} kg is the empty gripper's (within {REFINEMENT_KG} kg): "
                              "the model in use")
            self._cautious = False  # as a window the model describes
            self._held_for = []
            return
        # a refinement installs every estimate of the payload in use since its update, an
        # update the estimates it rests on, pooled by their information (inverse variances
        # of the mass; equal weights without them): single windows of a small payload
        # scatter by 10 %
        if kind == "refinement":
            # the estimates the model in use rests on (its own evidence when a rollback
            # emptied them, as the quiet refinement's)
            model = (self.payload_mass_kg, sd0, self.beta,
                     np.asarray(self.payload["com_m"], dtype=float))
            pool = (self._pool or [model]) + agreed
        else:
            pool = list(agreed)
        beta, m_pool, com, sd_pool = _pooled(pool)
        if to_prior:
            # the empty gripper is the prior itself (an estimate within REFINEMENT_KG of it
            # is the model the static CTC runs on: step 4), not a payload of a few grams
            beta, m_pool, pool = self.prior_beta.copy(), 0.0, []
        if kind == "update" and m_pool > 0 and self.flexible:
            refused = self._switch_refused(k1, m_pool, beta, rec)
            if refused:
                rec.update(decision="unsafe", reason=refused)
                return
        if not to_prior:
            # a return to the prior ends no episode of caution: a window the model
            # describes does (the payload that comes next still needs agreeing estimates);
            # nor does an update the switch check refused
            self._cautious = False
            self._held_for = []
        self._pool = pool
        # the window's fit -- its start state and the model it was fitted with, which the
        # installed one (pooled, or the prior) need not be -- for the flexible-joint CTC's
        # link estimate (the hand-over) when its estimate describes the window; the effective
        # sample is set by _identify once the window's wall time is known
        start = None if undescribed else (float(est.window_s[0]), est.start_state,
                                          np.asarray(est.beta, dtype=float))
        self._pending = (None, beta, dict(mass_kg=m_pool, com_m=com, mass_std=sd_pool)
                         if m_pool > 0 else None, mse, False, start)
        rec.update(decision=kind, reason=f"LR {st['lr']:.3g} > {threshold:.3g}"
                   + ("; back to the prior (the empty gripper)" if to_prior else "")
                   + (f", though {m:.3g} kg leaves {st['y_new']:.4g} pulses^2 (more than "
                      f"{INADEQUATE_FACTOR:g} quantisation floors, {floor:.4g})"
                      if undescribed else "")
                   + (", the second half of a window spanning a change" if rec.get("half_window")
                      else "")
                   + (f"; {len(self._pool)} estimates pooled: {m_pool:.3g} kg"
                      if len(self._pool) > 1 else "")
                   + (f"; {rec['switch_note']}" if rec.get("switch_note") else ""))

    def _quiet_refinement(self, k1, fit, rec, mse) -> None:
        """Windows the model in use describes refine it (module docstring, step 4).

        The window's estimate (plausible: inside the box, below its upper mass end and
        above :data:`REFINEMENT_KG`; explaining: its output error within the adequacy
        limit; with a standard error) is kept as a measurement of the payload in use.
        Once :data:`QUIET_WINDOWS` of them within 25 % + 50 g of the model's mass have
        come in since the model took effect, they are pooled with the model's own
        estimate by their information (:func:`_pooled`), and when the model's mass lies
        outside the combination's confidence interval at ``false_alarm`` -- ``q =
        (m_model - m_comb)**2 / sd_comb**2`` beyond the chi-square quantile with one
        degree of freedom -- the combination is installed (decision ``'refinement'``, no
        probation; on a flexible prior a heavier combination passes the switch check
        first).  For a model that is the robot's payload, ``q`` is at most a chi-square
        with one degree of freedom: a false alarm at most ``false_alarm``.  For a model
        that is itself an estimate with its standard error, ``q`` is a chi-square times
        the ratio of the windows' information to the model's: at most ``false_alarm``
        while the windows know no more than the model, and more often once they know
        more -- then the combination, which is installed, is the better estimate, and its
        information is the sum of both (the PUMA path's rule on the linear payload
        vector, :mod:`ctc.adaptive`).  Not after a change no payload explains was
        reported (the windows since measure the changed robot).
        """
        if self.payload is None or self._warned:
            # not after a change no payload explains was reported: the windows since then
            # measure the changed robot, not the payload (the PUMA path's rule too)
            return
        est, st = fit["est"], fit["st"]
        m, sd = float(est.mass_kg), float(est.x_std[0])
        if (st["y_new"] > fit["limit"] or self._at_mass_bound(m) or m <= REFINEMENT_KG
                or not np.isfinite(sd) or sd <= 0):
            return
        self._since.append((m, sd, np.asarray(est.beta, dtype=float),
                            np.asarray(est.com_m, dtype=float).copy()))
        m0 = self.payload_mass_kg
        sd0 = float(self.payload.get("mass_std", math.nan))
        same = [e for e in self._since if same_payload(e[0], m0)]
        if len(same) < QUIET_WINDOWS or not np.isfinite(sd0) or sd0 <= 0:
            return
        model = (m0, sd0, self.beta, np.asarray(self.payload["com_m"], dtype=float))
        beta, m_comb, com, sd_comb = _pooled([model] + same)
        q = (m0 - m_comb) ** 2 / sd_comb ** 2
        threshold = float(self._chi2.isf(self.false_alarm, 1))
        rec["quiet_wald"] = float(q)
        if not (q > threshold and same_payload(m_comb, m0)):
            return
        if self.flexible and m_comb > m0:
            # a heavier model raises the loop gain at the springs' modes: the switch check
            refused = self._switch_refused(k1, m_comb, beta, rec)
            if refused:
                rec.update(decision="unsafe", reason=refused)
                return
        # the estimates of the payload in use since its update (the model's own evidence
        # when a rollback emptied them)
        self._pool = (self._pool or [model]) + same
        self._since = []
        self._pending = (None, beta, dict(mass_kg=m_comb, com_m=com, mass_std=sd_comb), mse,
                         True, None)
        rec.update(decision="refinement",
                   reason=(f"the {len(same)} windows since the model took effect, pooled with "
                           f"its payload ({m0:.3g} +- {sd0:.2g} kg): {m_comb:.3g} +- "
                           f"{sd_comb:.2g} kg; the model lies outside its confidence interval, "
                           f"Wald {q:.3g} > {threshold:.3g}")
                   + (f"; {rec['switch_note']}" if rec.get("switch_note") else ""))

    def _switch_refused(self, k1, mass, beta, rec):
        """The switch check of a flexible prior (module docstring): None when the update to
        ``beta`` may take effect, else the reason it may not."""
        import copy

        import plant as _plant

        from .arm import FLEXIBLE_CHECK_S, GOAL_PULSES

        if any(same_payload(mass, m) for m in self._unsafe):
            return (f"{mass:.3g} kg is a payload the switch check refused; the model is kept")
        sel = getattr(self._ctc, "selection", None) or {}
        worsts = [sel.get("worst_flexible"), sel.get("worst_rigid_equivalent")]
        promised = (sel.get("worst_flexible") if isinstance(self._ctc, ArmFlexibleComputedTorque)
                    else sel.get("worst_rigid_equivalent"))
        if promised is None or not np.isfinite(promised):
            promised = min((w for w in worsts if w is not None and np.isfinite(w)),
                           default=GOAL_PULSES)
        bound = max(float(promised), GOAL_PULSES) + SWITCH_MARGIN_PULSES
        rig = self.prior["rig"]
        n = int(round(FLEXIBLE_CHECK_S / rig.sample_time_s))
        row = np.array(self.prior["plant_row"], dtype=float)
        row[:self.prior_beta.size] = beta

        def tracking(model):
            """Max |e| per joint after 0.1 s of the inner CTC with ``model`` (None: the one in
            use) on the identified arm carrying the payload (inf: the run failed)."""
            ctrl = copy.deepcopy(self._ctc)
            ctrl.envelope = None  # the law itself, as the design check saw it
            ctrl.reset()
            if model is not None:
                ctrl.set_beta(model, feedback_beta=self._feedback_for(model))
            try:
                r = _plant.simulate_closed_loop(
                    rig, row, ctrl, trajectory=self.trajectory, n_samples=n,
                    plant=self.prior["flexible_plant"],
                    substeps=int(self.prior.get("flexible_substeps") or 8))
                if r.success:
                    return np.asarray(r.max_abs_error(0.1), dtype=float)
            except ValueError:
                pass
            return np.full(self.n, math.inf)

        errs = tracking(beta)
        err = float(errs.max())
        rec["switch_check_pulses"] = err
        rec["switch_check_bound"] = bound
        if np.isfinite(err) and err <= bound:
            return None
        # the alternative to the switch: the model in use, kept on the arm carrying the payload;
        # better than it, and not lost (within the bound beyond which the design check counts
        # a run as lost, ctc.guard.lost_bound of the log)
        kept = float(tracking(None).max())
        rec["switch_check_kept_pulses"] = kept
        if np.all(errs <= lost_bound(self.log.e_pulses)) and err + SWITCH_GAIN_PULSES <= kept:
            rec["switch_note"] = (f"the switch check: {err:.4g} pulses after 0.1 s on the "
                                  f"identified arm carrying it, beyond the design's "
                                  f"{bound:.4g} but better than the model in use's {kept:.4g}")
            return None
        self._unsafe.append(mass)
        msg = (f"the controller cannot carry the {mass:.3g} kg payload it identified: with "
               f"that model, on the identified arm carrying it, it tracks "
               f"{err:.4g} pulses after 0.1 s, more than {bound:.4g} (its design check's "
               f"worst case {float(promised):.4g} + {SWITCH_MARGIN_PULSES:g}) and no better "
               f"than the model in use there ({kept:.4g}); the model in use is kept")
        self._event(k1, "unsafe", msg, mass_kg=mass, check_pulses=err)
        warnings.warn(msg, RuntimeWarning, stacklevel=4)
        return msg

    def _rival(self, wlog, window, est, m, st, rec):
        """The rival change that explains the window better than the payload estimate, or None.

        Each of :attr:`rivals` is fitted on the window under the model in use
        (:func:`identification.arm_payload.identify_arm_friction_change`, and on a
        flexible prior :func:`identification.arm_payload.identify_arm_drive_change`)
        and tested against the payload by Vuong's ``z`` (positive: the rival
        better).  Before a rival change has shown in this episode it must explain the
        window significantly better (``z`` beyond the normal quantile of
        ``false_alarm`` shared among the rivals); once it has (a window of the
        episode said so, or it was reported), the payload must explain the window
        significantly better than it.  Returns ``(cause, reason)`` of the rival
        furthest beyond its threshold; the fits go into the window's record
        (``<cause>_z``, ``<cause>_y``, ``<cause>_factors``).
        """
        best = None
        for cause in self.rivals:
            fit = self._identify_friction if cause == "friction" else self._identify_drive
            h = fit(wlog, self.prior, beta=self.beta, window_s=window, currents="logged",
                    workers=1)
            if not h.success:
                continue
            z = float(vuong_residual_statistic(est.residuals_pulses, h.residuals_pulses))
            if cause == "friction":
                factors = dict(viscous=h.viscous_factor.tolist(), coulomb=h.coulomb_factor.tolist())
                what = ("a friction change (viscous x" + " / x".join(
                    f"{v:.3g}" for v in h.viscous_factor) + ", Coulomb x" + " / x".join(
                    f"{v:.3g}" for v in h.coulomb_factor))
            else:
                factors = dict(stiffness=h.stiffness_factor.tolist(),
                               damping=h.damping_factor.tolist())
                what = ("a change of the joints' springs (stiffness x" + " / x".join(
                    f"{v:.3g}" for v in h.stiffness_factor) + ", damping x" + " / x".join(
                    f"{v:.3g}" for v in h.damping_factor))
            rec.update({f"{cause}_z": z, f"{cause}_y": float(h.fun),
                        f"{cause}_factors": factors})
            shown = cause in self._named or cause in self._causes
            threshold = -self._rival_z if shown else self._rival_z
            if z > threshold and (best is None or z - threshold > best[0]):
                best = (z - threshold, cause,
                        f"{what}, {h.fun:.4g} pulses^2) explains the window better than the "
                        f"payload ({m:.3g} kg, {st['y_new']:.4g}): Vuong z {z:.3g} > "
                        f"{threshold:.3g}")
        return None if best is None else best[1:]

    def _unexplained(self, k1, rec) -> None:
        """A window no plausible payload describes: reported the second time in a row."""
        self._odd += 1
        self._agree = []
        self._since = []  # the robot changed: not measurements of the payload in use
        self._causes.append(rec.get("cause", "unknown"))
        if self._odd >= 2:
            self._cautious = True
            self._held_for = []
            if not self._warned:
                what = "friction, springs" if self.flexible else "friction, damping"
                msg = (f"a change the payload model does not explain at t = {k1 * self.ts:.3f} s "
                       f"({what}, a collision?): {rec['reason']}; the model is kept")
                # the rival the episode's windows named last, else a change no rival describes
                named = [c for c in self._causes if c in self.rivals]
                cause = named[-1] if named else "unknown"
                if named:
                    self._named.add(cause)
                self._event(k1, "unexplained", msg, cause=cause)
                warnings.warn(msg, UnmodelledChangeWarning, stacklevel=3)
                self._warned = True

    def _at_mass_bound(self, m) -> bool:
        """Whether a mass (kg) is at the upper end of the box (within 1 % of its width): the
        optimiser's edge, not the robot's payload."""
        lo, hi = self.bounds[0]
        return bool(m >= hi - 0.01 * (hi - lo))

    def _diagnose(self, k1) -> None:
        """What changed, read from the windows after the watchdog's fallback (module docstring).

        The window ending before sample ``k1`` is fitted as every window is (the
        currents the drive applied replayed, so the P law needs no model), with
        the friction rival beside the payload.  Two successive windows that say
        the same name the change.  A hypothesis *describes* a window when its
        output error is within :data:`identification.flexible.INADEQUATE_FACTOR`
        quantisation floors (a payload also inside its box).  Friction: the
        window shows a change and the friction rival is ahead of the payload by
        Vuong's ``z`` beyond the normal quantile of ``false_alarm``, or
        describes the window where no payload does (event ``'unexplained'``,
        ``cause='friction'``).  A payload: significant against the model in
        use, describing the window, and friction trailing it by that margin or
        not describing it -- one payload in both windows (event
        ``'diagnosis'``, ``cause='payload'``).  Unknown: neither the model in
        use, nor a payload, nor friction describes the window
        (``'unexplained'``, ``cause='unknown'``).  The P law keeps
        the arm; the diagnosis ends when it has named the change.
        """
        from identification.flexible import INADEQUATE_FACTOR

        k0 = k1 - self.window_n
        t_wall = time.perf_counter()
        wlog = self._window_log(k1)
        fit = self._fit_window(wlog, k0, k1)
        rec = dict(window_s=fit["window"], named=None, said=None)
        self.diagnoses.append(rec)
        if not fit["ok"]:
            rec["error"] = fit["est"].message if not fit["est"].success else fit["now"].message
            return
        est, st, limit = fit["est"], fit["st"], fit["limit"]
        m = float(est.mass_kg)
        fr = self._identify_friction(wlog, self.prior, beta=self.beta, window_s=fit["window"],
                                     currents="logged", workers=1)
        z = (float(vuong_residual_statistic(est.residuals_pulses, fr.residuals_pulses))
             if fr.success else math.nan)
        rec.update(mass_kg=m, lr=float(st["lr"]), threshold=fit["threshold"],
                   y_now=float(st["y_now"]), y_new=float(st["y_new"]), limit=float(limit),
                   friction_z=z, friction_y=float(fr.fun) if fr.success else math.nan,
                   friction_factors=dict(viscous=fr.viscous_factor.tolist(),
                                         coulomb=fr.coulomb_factor.tolist())
                   if fr.success else None)
        changed = st["lr"] > fit["threshold"] or st["y_now"] > limit
        inside = not self._at_mass_bound(m)
        # each hypothesis describes the window or not (within INADEQUATE_FACTOR quantisation
        # floors); between two that both do, or neither, Vuong's test decides
        payload_fits = bool(st["y_new"] <= limit and inside)
        friction_fits = bool(fr.success and fr.fun <= limit)
        if changed and (z > self._z_threshold or (friction_fits and not payload_fits)):
            rec["said"] = "friction"
        elif (st["lr"] > fit["threshold"] and payload_fits
              and (z < -self._z_threshold or not friction_fits)):
            rec["said"] = "payload"
        elif st["y_now"] > limit and not payload_fits and not friction_fits:
            rec["said"] = "unknown"
        rec["elapsed_s"] = time.perf_counter() - t_wall
        last = [d for d in self.diagnoses if "error" not in d][-2:]
        said = [d["said"] for d in last]
        if len(said) < 2 or said[0] != said[1] or said[1] is None:
            return
        if said[1] == "payload" and not same_payload(last[0]["mass_kg"], m):
            return
        self.diagnosis = rec["named"] = said[1]
        t_fb = self._ctc.fallback_t_s
        if said[1] == "payload":
            self._event(k1, "diagnosis",
                        f"after the fallback to the P law at t = {t_fb:.3f} s, a payload of "
                        f"{m:.3g} kg describes two successive windows ({st['y_new']:.4g} "
                        f"pulses^2 in the last) and a friction change does not, or trails it "
                        f"({rec['friction_y']:.4g} pulses^2, Vuong z {z:.3g}); the P law keeps "
                        "the arm", mass_kg=m, cause="payload",
                        payload=dict(mass_kg=m, com_m=np.asarray(est.com_m, float).tolist()))
            return
        if said[1] == "friction":
            what = ("a friction change (viscous x" + " / x".join(
                f"{v:.3g}" for v in fr.viscous_factor) + ", Coulomb x" + " / x".join(
                f"{v:.3g}" for v in fr.coulomb_factor) + f", {fr.fun:.4g} pulses^2) explains "
                f"two successive windows better than a payload ({m:.3g} kg, {st['y_new']:.4g}; "
                f"Vuong z {z:.3g})")
        else:
            what = (f"neither the model in use ({st['y_now']:.4g} pulses^2), nor a payload "
                    f"({st['y_new']:.4g}), nor a friction change describes two successive "
                    f"windows: more than {INADEQUATE_FACTOR:g} quantisation floors "
                    f"({fit['floor']:.4g})")
        msg = (f"after the fallback to the P law at t = {t_fb:.3f} s, {what}; the P law keeps "
               "the arm")
        self._event(k1, "unexplained", msg, cause=said[1])
        warnings.warn(msg, UnmodelledChangeWarning, stacklevel=3)

    def _judge_probation(self, k0, k1, mse) -> None:
        """Rollback: the first whole window after an update tracks clearly worse."""
        if self._probation is None or k0 < self._probation[0]:
            return
        k_eff, trigger, beta_before, payload_before = self._probation
        self._probation = None
        if mse > self.explain_factor * max(trigger, 1.0):
            self._roll_back(k1, beta_before, payload_before,
                            f"tracking mean square {mse:.3g} pulses^2 after the update, "
                            f"> {self.explain_factor:g} x {max(trigger, 1.0):.3g} before it")

    def _roll_back(self, k1, beta, payload, why) -> None:
        """Back to ``beta`` (``payload``) at sample ``k1``, the model in use rejected: only
        agreeing estimates update, none of that payload until a window shows no change."""
        self._rejected = self.payload_mass_kg
        self._probation = None
        self._pool = []
        self._since = []
        self._install(beta, payload)
        self.payload_history.append((k1 * self.ts, self.payload_mass_kg))
        self._cautious = True
        self._held_for = []
        self._agree = []
        self._trigger_mse = None  # the restored model's own trigger is not known
        self._event(k1, "rollback", f"{why}: back to {self.payload_mass_kg:.3g} kg")

    def _diverging(self, k0, k1, mse) -> bool:
        """The divergence guard (module docstring, step 4): True when it returned to the prior.

        Two whole windows under one payload model, the second tracking worse than the first,
        than the window that brought the model in, and :data:`ctc.adaptive.DIVERGE_FACTOR`
        times the largest mean square of a window without change on the prior (and one
        pulse^2): the model makes the loop diverge -- a heavier link model can take a
        flexible-joint CTC past its margins, slowly, after its first window passed the
        probation -- and the prior, the static CTC's model, takes over at once (the PUMA
        path's guard, :mod:`ctc.adaptive` step 4).
        """
        t_model = self.payload_history[-1][0]
        one_model = k0 * self.ts >= t_model - 1e-12
        prev, self._last_window = self._last_window, ((t_model, mse) if one_model else None)
        if not (one_model and prev is not None and prev[0] == t_model and mse > prev[1]
                and self.payload is not None and self._mse_normal is not None
                and mse > (self._trigger_mse or 0.0)
                and mse > DIVERGE_FACTOR * max(self._mse_normal, 1.0)):
            return False
        self.identifications.append(dict(
            window_s=(k0 * self.ts, (k1 - 1) * self.ts), decision="diverging",
            mass_kg=math.nan, mass_std=math.nan, lr=math.nan, threshold=math.nan,
            y_now=math.nan, y_new=math.nan, tracking_mse=mse, elapsed_s=0.0,
            reason=(f"tracking mean square {mse:.3g} pulses^2, up from {prev[1]:.3g} under the "
                    f"{self.payload_mass_kg:.3g} kg model; the prior's windows without change "
                    f"reached {self._mse_normal:.3g}")))
        self._roll_back(k1, self.prior_beta.copy(), None,
                        f"tracking diverging ({mse:.3g} pulses^2 mean square, more than "
                        f"{DIVERGE_FACTOR:g} x the largest without change on the prior, "
                        f"{self._mse_normal:.3g}, and growing)")
        return True

    # ------------------------------------------------------------------ views
    @property
    def payload_mass_kg(self) -> float:
        """Mass (kg) of the payload in use (0.0 without one)."""
        return 0.0 if self.payload is None else float(self.payload["mass_kg"])

    @property
    def fallback_t_s(self):
        """Time (s) the inner controller's watchdog handed the arm to the P law (None: never)."""
        return self._ctc.fallback_t_s

    @property
    def pending(self):
        """A model identified but not yet in effect: ``(t_s, mass_kg)``, the time (s) it
        takes effect and its payload's mass (kg; 0.0 for the empty gripper), or None.  At
        the end of a run, the model its last window found."""
        if self._pending is None or self._pending[0] is None:
            return None
        payload = self._pending[2]
        return (self._pending[0] * self.ts, 0.0 if payload is None else float(payload["mass_kg"]))

    @property
    def limit(self):
        """The drive's current limit (A), per joint."""
        return self._ctc.limit

    def __repr__(self) -> str:
        return (f"ArmAdaptiveComputedTorque({self.prior['plant'].model.name!r}, "
                f"window_s={self.window_s:g}, payload {self.payload_mass_kg:.3g} kg)")
