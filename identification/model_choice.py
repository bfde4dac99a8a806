"""The model choice's rule, for every robot: whether a richer model beats a simpler one.

The rule of :func:`identification.arm.identify_arm` and of the PUMA 560
path's :func:`identification.flexible.apply_model`: a richer model (the
two-mass joints, the backlash) is chosen over a simpler one on the
held-back blocks of the log's prediction error (:class:`ModelImprovement`:
half the cost, a paired t per held-back block, the quantisation floor, or
half the excess over it).  Its constants and statistic live here, below
both paths, so that neither imports the other for them.
"""
from __future__ import annotations

import math

import numpy as np

from .refinement import HOLD_BLOCK_S, HOLD_EVERY

__all__ = ["CHOICE_RATIO", "ARM_FLOOR_FACTOR", "CHOICE_T", "BACKLASH_T", "EXCESS_T",
           "ModelImprovement", "held_back_paired_t"]

#: A richer model (springs, backlash) is chosen when its held-back cost is below this times
#: the simpler's, or its excess over the quantisation floor below this times the simpler's
#: (or by the other tests of :class:`identification.model_choice.ModelImprovement`).
CHOICE_RATIO = 0.5

#: ``identify_arm(model="auto")`` keeps the rigid model without fitting the two-mass
#: joints when its prediction-error cost is at most this many quantisation floors
#: (``n / 12`` pulse^2; a model chosen within it on the held-back blocks skips the backlash
#: likewise).  A model that describes
#: the robot leaves the quantisation noise alone: on 24 rigid robots of the independent
#: simulator (``benchmarks/bench_arm_floor.py --seed 20262901``: planar, PUMA 560 joints
#: 1-3, random DH and random URDF chains of 2-4 joints, 500-4096 ppr, friction known or
#: identified) the rigid fit's cost was 0.990-1.033 floors.  The PUMA 560 path's
#: :data:`identification.flexible.FLOOR_FACTOR` (2) lets a compliant arm's rigid fit at
#: 1.4-1.8 floors pass for the noise, and its base parameters carry the springs' bend
#: (1.2-3.3 % off; ``docs/tutorial_your_robot.rst``, "Compliant joints near the floor").
ARM_FLOOR_FACTOR = 1.1

#: The two-mass joints are chosen when they halve the rigid model's held-back cost
#: (:data:`identification.model_choice.CHOICE_RATIO`), or lower the cost of the held-back blocks
#: on average by more than this many standard errors of the mean (a one-sided paired t
#: test; blocks 0.3 s apart are nearly independent, unlike the quantisation errors of
#: neighbouring samples: 0.6 % false alarms with a 5 s log's 12 held-back blocks, 1.2 %
#: with a 3 s log's 7), or reach the quantisation floor (:data:`ARM_FLOOR_FACTOR`, on the
#: held-back blocks) where the rigid model does not: a spring that is real but stiff
#: improves the prediction by less than half (and the excess over the floor halved:
#: :class:`ModelImprovement`).  On the held-back blocks the floor is that of
#: the whole log: the two-mass models chosen on 18 compliant draws of
#: ``benchmarks/bench_arms.py`` (``docs/figures/bench_arms_compliant.txt``,
#: ``..._20262921.txt``, ``bench_arms_random_compliant_20262831.txt``) predict them to
#: 0.978-1.041 floors, but for two fits that missed the robot (1.70 and 4.98).
CHOICE_T = 3.0

#: The backlash is kept when, against the model chosen before it (the springs, or the rigid
#: model when the springs were not chosen), it passes the same tests
#: (:class:`ModelImprovement`): half the held-back cost, this paired t (:data:`CHOICE_T`),
#: the floor, or half the excess over the floor.
BACKLASH_T = 3.0

#: The excess test of :class:`ModelImprovement` (half the simpler model's excess over the
#: quantisation floor) also asks the held-back blocks for some consistency: a paired t
#: above this (about one chance in five for a model no better, over 6-12 blocks), so that
#: one block alone (a reversal, say) does not decide what the costs' levels say.
EXCESS_T = 1.0


class ModelImprovement:
    """Whether a richer model's held-back prediction beats a simpler one's, and why (a sentence).

    The model choice's rule, for every robot (:func:`identification.arm.identify_arm` and the
    PUMA 560 path's :func:`identification.flexible.apply_model`): the
    richer model is *better* when its held-back prediction-error cost is
    lower and one of these holds:

    * ``"ratio"``: below :data:`~identification.model_choice.CHOICE_RATIO` times
      the simpler's;
    * ``"paired_t"``: lower per held-back block by more than ``t_threshold``
      standard errors (:func:`held_back_paired_t`);
    * ``"floor"``: at the quantisation floor (within :data:`ARM_FLOOR_FACTOR`
      floors) where the simpler's is not;
    * ``"excess"``: the simpler's is above the floor's allowance, the
      richer model leaves less than ``CHOICE_RATIO`` of its *excess* over
      the floor (``c - floor``, the model error's share of the cost), and
      the held-back blocks agree at least weakly (paired t above
      :data:`EXCESS_T`): the ratio test on what a model can explain.  Near
      the floor the raw ratio cannot reach one half even for a model of
      the robot (springs at 2.09 floors against a backlash fit's 1.13 is a
      ratio of 0.54, ``docs/figures/model_choice_indep_20261327_0046.txt``),
      while a model error halved is the same evidence at any distance from
      the floor.

    Parameters
    ----------
    c_new, c_old : float
        Held-back costs (pulses^2) of the richer and of the simpler model.
    r_new, r_old : array_like, shape (n_samples * n_joints,)
        Their prediction residuals (pulses), sample-major, the whole log.
    floor : float
        The quantisation floor (pulses^2) of the held-back samples (their
        count / 12, :func:`identification.flexible.quantisation_floor`).
    log : plant.ExperimentLog or plant.logs.arm_log.ArmLog
        The log (its joints and sample time place the held-back blocks).
    t_threshold : float
        The paired t test's threshold (:data:`CHOICE_T`, :data:`BACKLASH_T`).

    Attributes
    ----------
    t : float
        The paired t statistic (> 0: the richer model better).
    test : str or None
        The first test passed (``"ratio"``, ``"paired_t"``, ``"floor"``,
        ``"excess"``), or None.
    why : str
        The sentence the model choice's ``reason`` quotes.
    """

    def __init__(self, c_new, r_new, c_old, r_old, floor, log, t_threshold):
        self.t = held_back_paired_t(r_old, r_new, log)
        floor_at = ARM_FLOOR_FACTOR * floor
        ratio = c_new / c_old if c_old > 0 else 1.0
        applies = c_old > floor_at
        excess = (c_new - floor) / (c_old - floor) if applies else math.nan
        lower = bool(np.isfinite(c_new) and c_new < c_old)
        tests = (("ratio", ratio < CHOICE_RATIO, f"cost ratio {ratio:.3g} < {CHOICE_RATIO}"),
                 ("paired_t", self.t > t_threshold, f"paired t {self.t:.3g} > {t_threshold:g}"),
                 ("floor", c_new <= floor_at < c_old,
                  f"at the quantisation floor ({c_new:.4g} <= {floor_at:.4g} pulses^2), the "
                  f"simpler model not ({c_old:.4g})"),
                 ("excess", applies and excess < CHOICE_RATIO and self.t > EXCESS_T,
                  f"excess over the quantisation floor {floor:.4g} pulses^2 ratio {excess:.3g} "
                  f"< {CHOICE_RATIO} ({c_new - floor:.4g} / {c_old - floor:.4g}), paired t "
                  f"{self.t:.3g} > {EXCESS_T:g}"))
        passed = [(name, why) for name, ok, why in tests if lower and ok]
        #: the first test passed (``"ratio"``, ``"paired_t"``, ``"floor"``, ``"excess"``), or None
        self.test = passed[0][0] if passed else None
        self.why = (passed[0][1] if passed else
                    f"cost ratio {ratio:.3g} >= {CHOICE_RATIO}, paired t {self.t:.3g} <= "
                    f"{t_threshold:g}, held-back cost {c_new:.4g} pulses^2 "
                    + (("above the floor, excess ratio "
                        + (f"{excess:.3g}" if applies else "n/a (the simpler at the floor)")
                        + f" (needs < {CHOICE_RATIO} with paired t > {EXCESS_T:g})")
                       if c_new > floor_at else "with the simpler model at the floor too"))

    @property
    def better(self) -> bool:
        """Whether a test passed."""
        return self.test is not None


def held_back_paired_t(ra, rb, log) -> float:
    """Paired t statistic of the held-back block costs of residuals ``ra`` minus ``rb``.

    Per held-back block (every :data:`~identification.refinement.HOLD_EVERY`-th
    block of :data:`~identification.refinement.HOLD_BLOCK_S` s) the cost
    difference ``sum ra^2 - sum rb^2``; their mean over the standard error
    of the mean (Student's paired t; blocks 0.3 s apart are nearly
    independent, unlike the quantisation errors of neighbouring samples).

    Parameters
    ----------
    ra, rb : array_like, shape (n_samples * n_joints,)
        Prediction residuals (pulses), sample-major.
    log : plant.ExperimentLog or plant.logs.arm_log.ArmLog
        The log (its joints: the columns of ``e_pulses``; ``rig.sample_time_s``).

    Returns
    -------
    float
        > 0 when ``rb`` predicts the held-back blocks better; 0 with fewer
        than three blocks or a failed prediction (no evidence).
    """
    n = int(np.shape(log.e_pulses)[1])
    ra = np.asarray(ra, dtype=float).reshape(-1, n)
    rb = np.asarray(rb, dtype=float).reshape(-1, n)
    block = max(1, int(round(HOLD_BLOCK_S / log.rig.sample_time_s)))
    idx = np.arange(ra.shape[0]) // block
    held = idx % HOLD_EVERY == HOLD_EVERY - 1
    ids = np.unique(idx[held])
    d = np.array([np.sum(ra[idx == b] ** 2) - np.sum(rb[idx == b] ** 2) for b in ids])
    if d.size < 3 or not np.all(np.isfinite(d)):
        return 0.0  # too few blocks, or a failed prediction: no evidence
    sd = d.std(ddof=1)
    if sd == 0:
        return math.inf if d.mean() > 0 else 0.0
    return float(d.mean() / (sd / math.sqrt(d.size)))
