"""Regenerate the figures quoted in README.md and docs/*.rst from actual runs.

One script for every number and image the README and the documentation
quote.  It runs the library, the examples and the benchmarks on the bundled
logs (and, for the comparisons with the true parameters, on the truth files
of the emulated development logs in ``tests/data``) and writes

* ``docs/figures.json``: every figure, per section, with the machine, the
  commit and the date of the run (written atomically: a failed run leaves
  the previous file);
* ``docs/images/*.png``: the images the pages show
  (``identification_convergence.png``, ``identification_tracking_errors.png``,
  ``online_payload_errors.png``, ``real_rigs_spectrum.png``, ``scaling.png``,
  ``optimisers_convergence.png``);
* ``docs/figures/``: the raw outputs of the examples and benchmarks it ran
  (JSON results, printed tables).

Sections (``--sections``, default all; several minutes on 2 cores, most of
it in ``optimisers``):

``simulator``
    How exactly the simulator reproduces the rigid development logs with
    the true f (identical samples, within +-1 pulse) at the default substeps.
``identification``
    ``identify`` on the bundled log, default method and ``method="paper"``,
    seed 0: f, errors against the truth, output error, simulations, wall
    time, cross-validation on the validation log; the CLI's ``--example``
    wall time.
``alteration``
    ``examples/alteration_study.py``: 10 seeds per method, with the truth
    and the validation log.
``ctc``
    ``examples/ctc_vs_p.py`` with the true robots (``--truth``,
    ``--drill-truth``): P vs CTC max |e|, robustness, flexible robot.
``real_rigs``
    ``examples/real_rigs.py`` with the truth (on the version before the robust
    design's selection at the encoder's resolution:
    ``figures/real_rigs_before_tied_design.txt``): spectrum, cut-off, drill-log f
    errors, on-line payload mass and wall time; the spectrum image.
``speed``
    ``benchmarks/bench_simulate.py``: cost per simulation, scaling, full
    identification times; the scaling image.
``optimisers``
    ``benchmarks/bench_optimisers.py``: GA, GA + refinement, DE, CMA-ES on one
    budget; the convergence image.
``flexible``
    ``benchmarks/bench_flexible.py --drill``: rigid vs flexible model vs
    IDIM-LS on held-out flexible logs and the drill log, and the CTC of each.
``methods``
    ``benchmarks/bench_methods.py``: the methods comparison table (GA, GA +
    refinement, DE, CMA-ES, IDIM-LS, IDIM-IV) on development and generated logs.
``coverage``
    ``benchmarks/bench_coverage.py``: coverage of f +- 1.96 f_std over
    generated logs.
``excitation``
    ``benchmarks/bench_excitation.py``: a designed 1.5 s excitation against
    the paper trajectory.
``online_payload``
    ``benchmarks/bench_online_payload.py``: the wall time of one payload
    identification on 100 and 200 ms windows; ``examples/online_payload.py``
    and its pick-up image.
``robustness``
    ``benchmarks/bench_robustness.py --n 106 --seed 20261122 --jobs 2``: the
    randomized suite of logs from the independent simulator (needs the
    ``bench`` extra, Robotics Toolbox for Python; about 40 min on 2 cores):
    ``figures/robustness.rst`` (success rates, worst five) and
    ``figures/robustness.txt`` (every log).
``changes``
    ``benchmarks/bench_changes.py --n 60 --seed 20261122 --jobs 2``: mid-run
    changes on the independent simulator, P / static CTC / adaptive CTC
    (``figures/changes.rst``, ``figures/changes.txt``).
``changes_updates``
    ``benchmarks/bench_changes.py --n 60 --cases ... --seed 20261122 --jobs 2``
    on the cases of ``changes`` in which the adaptive CTC made an update
    (``CHANGES_UPDATE_CASES``: 18 flexible, 17 rigid), the check of a change
    to how an update pools its evidence
    (``figures/changes_updates_flexible.rst``, ``figures/changes_updates_rigid.rst``).
``changes_reported``
    ``benchmarks/bench_changes.py --cases ... --out <a fresh folder>``
    on both draws (seeds 20261122 and 20261123) on the cases of ``changes`` and of
    ``figures/changes_fresh.txt`` with an ``'unexplained'`` event and an update
    (``CHANGES_REPORTED_CASES``): the only cases in which an update can wait for
    agreeing estimates because the episode's change was reported
    (``figures/changes_reported_20261122.rst``, ``figures/changes_reported_20261123.rst``).
``changes_third``
    ``benchmarks/bench_changes.py --n 24 --seed 20261126 --jobs 2`` in a fresh
    output folder: a third draw of the changes benchmark, on a seed chosen before
    its first run (``figures/changes_20261126.rst``, ``figures/changes_20261126.txt``).
``changes_fourth``
    ``benchmarks/bench_changes.py --n 58 --seed 20261130 --jobs 2`` in a fresh
    output folder: a fourth draw, on a seed chosen before its first run, 56
    cases (``figures/changes_20261130.rst``, ``figures/changes_20261130.txt``;
    about 110 min on 2 cores).  The saved figures are of the version whose
    robust flexible-joint design tries integral action too: its 35 flexible
    cases were rerun in the first run's folder, the rigid ones (which that
    version does not change) kept.
``current_cap``
    ``benchmarks/bench_design_current.py --seed 20261130 --cases`` the fourth
    draw's 18 flexible payload changes (``figures/design_current_20261130.txt``:
    per case the one-pulse current step, the tracking, the samples at full
    scale and the current's chatter of the robust design, the same capped at
    a tenth of full scale and the default gains; about 2 min a case), and the
    fourth draw rerun with ``--max-current-per-pulse 0.1`` in a fresh output
    folder (``figures/changes_20261130_cap01_run.txt``).  The selection at
    the encoder's resolution (:func:`ctc.flexible.tied_choice`) against the
    strict minimax on the 12 flexible payload changes among the first 70
    draws of a seed chosen before their run, 20261328
    (``bench_design_current.py --seed 20261328 --designs from_result,tie0
    --cases`` those 12 ``--jobs 2``: ``figures/design_current_20261328.txt``;
    the logs and priors of its probe run reused through ``--robust-out`` and
    ``--out``), and the sixth draw's flexible cases whose design that
    selection changes, rerun on it (``bench_changes.py --n 58 --seed
    20261327 --cases 0,4,6,8,33,34,35,39,40,46,47,50,52,53,57 --jobs 2`` with
    the priors of the whole draw's run copied into a fresh ``--out``:
    ``figures/changes_20261327_tied_design_run.txt``; case 0050's record,
    ``figures/changes_20261327_case_50_tied_design.json``, is that run's
    ``--out/cases`` file; of 0033, 0050 and 0057 the designs by both rules,
    ``bench_design_current.py --seed 20261327 --designs from_result,tie0
    --cases 33,50,57 --jobs 2`` with that ``--out``:
    ``figures/design_current_20261327_33_50_57.txt``); the draw's table is
    then ``bench_changes.py --n 58 --seed 20261327 --jobs 1`` over that folder
    with the other 41 cases of the whole run copied in (their controllers
    are the same; the table before, ``figures/changes_20261327_before_tied_design.txt``).
    On a version that held one window's update a rival explains better
    however the arm tracks, with a payload in use or not, the draw was rerun
    whole (``bench_changes.py --n 58 --seed 20261327 --jobs 2`` with the whole
    run's priors copied into a fresh ``--out``; about 35 min; its windows'
    decisions are the version before's in every case but 0048, in which no
    payload is ever in use, so it is also the run of the version that holds
    them only with no payload in use): its table is
    ``figures/changes_20261327.txt``, ``.rst`` (the version before's,
    ``figures/changes_20261327_before_rival_hold_run.txt``); and every
    flexible robot of the draw given a stiffness x0.7 change at a random
    time (``benchmarks/bench_stiffness_changes.py --seed 20261327
    --change-seed 20261379 --out`` that folder: on the version before with
    ``--jobs 1`` beside the wider rule's run, about 43 min,
    ``figures/stiffness_changes_20261327_before_rival_hold_run.txt``; on this
    version with ``--jobs 2``, about 12 min,
    ``figures/stiffness_changes_20261327.txt``).  The
    sixth draw's three cases with a named stiffness change, rerun on the
    version whose empty gripper meets the rival changes after one
    (``bench_changes.py --n 58 --seed 20261327 --cases 24,35,53 --jobs 2``
    with the whole run's priors copied into a fresh ``--out``:
    ``figures/changes_20261327_drive_named_cases.txt``), and the draw rerun
    whole on a quiet refinement tried and dropped (the model pooled only
    with windows it is one payload with; ``--n 58 --seed 20261327 --jobs 2``
    likewise: ``figures/changes_20261327_one_payload_refinement_run.txt``).
``changes_inconsistent``
    ``benchmarks/bench_changes.py --n 58 --seed 20261130 --cases 9,21,36,55
    --jobs 2`` with fresh output and robustness folders: the fourth draw's cases
    with an ``'unexplained'`` and an ``'update'`` event, the only ones the end of
    an inconsistent pause on agreeing estimates that describe their windows can
    move (``figures/changes_inconsistent_20261130.rst``,
    ``figures/changes_inconsistent_20261130_run.txt``; about 15 min, run with
    ``--jobs 1`` beside another benchmark; the same cases on the version before,
    the same script at commit d0309a3:
    ``figures/changes_inconsistent_20261130_before_run.txt``).
    The fourth draw's cases 0016, 0028 and 0055 with fresh output and
    robustness folders on the version before (commit d0309a3, ``--cases
    16,28,55``): ``figures/changes_20261130_rerun_run.txt``.
``changes_fifth``
    ``benchmarks/bench_changes.py --n 58 --seed 20261271 --jobs 2`` with fresh
    output and robustness folders (every prior identified by this version): a
    fifth draw, on a seed chosen before its first run
    (``figures/changes_20261271.rst``, ``figures/changes_20261271_run.txt``;
    39-50 min on 2 cores).  Its first run, on the version before the
    diagnosis of the P law's windows after a fallback and before every
    estimate was tested against the empty gripper:
    ``figures/changes_20261271_before_empty_gripper_run.txt``; its second, on
    the version before the quiet refinement (:mod:`ctc.adaptive`, step 3):
    ``figures/changes_20261271_before_quiet_refinement_run.txt``; its third,
    on the version before a refinement pooled only the estimates that are one
    payload with its own (Wald's test, step 3):
    ``figures/changes_20261271_before_wald_pool_run.txt``; its fourth, on the
    version after it (Wald's pool) and on the machine of that stop:
    ``figures/changes_20261271_wald_pool_run.txt``.  The run in
    ``figures/changes_20261271_run.txt`` is on the version whose
    following-error limit trips on a level and a time (:mod:`ctc.guard`);
    beside it, the version before (commit e24863d) on the same machine, with
    that run's logs and priors: ``figures/changes_20261271_before_dwell_run.txt``.  Its three
    cases with an inconsistent decision on the version before the end of an
    inconsistent pause on agreeing
    estimates (the same script at commit d0309a3, ``--cases 15,44,45`` with
    the run's logs and priors): ``figures/changes_20261271_inconsistent_before_run.txt``.
``changes_fallback``
    ``benchmarks/bench_changes.py --n 58 --seed 20261271 --cases 3,8,9,23
    --jobs 2`` and ``--seed 20261327 --cases 2,21,25``, each with fresh output
    and robustness folders: the fifth and sixth draws' cases whose adaptive
    CTC fell back to the P law, the only ones the diagnosis of the P law's
    windows (:mod:`ctc.adaptive`, step 6) can touch
    (``figures/changes_fallback_20261271.rst``, ``..._20261327.rst`` and their
    ``_run.txt``).
``changes_sixth``
    ``benchmarks/bench_changes.py --n 58 --seed 20261327 --jobs 2`` with fresh
    output and robustness folders: a sixth draw, on a seed chosen before its
    first run (``figures/changes_20261327.rst``, its report
    ``figures/changes_20261327.txt``: its sixth run, on the version whose PUMA
    model choice uses every robot's rule (:class:`identification.model_choice.ModelImprovement`),
    with the robustness suite's logs in ``benchmarks/out/robustness`` and every
    prior made anew, ``--out`` fresh; its stdout's progress lines were not kept.
    The version before's, the fifth run below:
    ``figures/changes_20261327_before_model_choice.txt`` (its report)
    and ``..._before_model_choice_run.txt``).  Its first run,
    on the version that diagnosed the P law's windows after a fallback with
    summed Vuong terms and before every estimate was tested against the
    empty gripper: ``figures/changes_20261327_before_empty_gripper_run.txt``;
    its second, on the version before the quiet refinement (:mod:`ctc.adaptive`,
    step 3): ``figures/changes_20261327_before_quiet_refinement_run.txt``; its
    third, on the version before a refinement pooled only the estimates that
    are one payload with its own (Wald's test, step 3):
    ``figures/changes_20261327_before_wald_pool_run.txt``.  Its fourth and
    fifth runs, and the version before the fifth beside it, are named as the
    fifth draw's (``..._wald_pool_run.txt``, ``..._before_model_choice_run.txt``,
    ``..._before_dwell_run.txt``; the version before was given the fifth
    run's logs and priors by ``--robust-out`` and ``--out``: the
    identification does not involve the limit).  Four of its cases run again on
    another machine with the same code (``--cases 33,52`` and ``--cases 20,21``,
    fresh folders): ``figures/changes_20261327_cases_33_52_rerun.txt``,
    ``..._cases_20_21_rerun.txt``.  The model choice's excess test
    (:class:`identification.model_choice.ModelImprovement`, now the PUMA path's rule
    too) on one of its logs, ``tests/data/independent/indep_20261327_0046.csv``:
    ``python -m identification tests/data/independent/indep_20261327_0046.csv``
    (``figures/model_choice_indep_20261327_0046.txt``); the friction box widened
    on another, ``python -m identification tests/data/independent/indep_20261327_0054.csv``
    (``figures/friction_box_indep_20261327_0054.txt``), and that draw's case of the
    changes benchmark rerun alone on the version that widens it
    (``--n 58 --seed 20261327 --cases 54 --jobs 1`` with fresh ``--out``:
    ``figures/changes_20261327_case_54_friction_box_run.txt``).  The ranges of
    the joint parameters a log leaves open
    (:func:`identification.flexible.joint_intervals`) against the truth and the
    standard errors on that draw's compliant robots:
    ``benchmarks/bench_joint_intervals.py --n 58 --seed 20261327 --jobs 2 --txt
    docs/figures/joint_intervals_20261327.txt``; on its log 0021,
    ``python -m identification tests/data/independent/indep_20261327_0021.csv``
    (``figures/joint_intervals_indep_20261327_0021.txt``), and that draw's case 21
    of the changes benchmark rerun alone on the version whose CTC checks those
    ranges (``--cases 21 --jobs 1``, fresh ``--out``, stdout:
    ``figures/changes_20261327_case_21_joint_ranges_run.txt``).
``changes_seventh``
    ``benchmarks/bench_changes.py --n 58 --seed 20261329 --jobs 2`` with fresh
    output and robustness folders: a seventh draw, on a seed chosen before its
    first run, run once, on the version of the sixth draw's table (its report
    ``figures/changes_20261329_run.txt``; about 65 min on 2 cores beside other runs);
    then the same command over that run's ``--out`` folder, which rescored its cached
    cases with the target added after it (no payload installed after a non-payload
    change): ``figures/changes_20261329.txt``, ``.rst``; case 0057's record, the run's
    ``cases/indep_20261329_0057.json``: ``figures/changes_20261329_case_57.json``.
``arms``
    ``benchmarks/bench_arms.py --n 10 8 6 --seed 20261122``: any serial arm
    (planar two-link, PUMA joints 1-3, six-joint PUMA) on logs of the
    independent simulator (``figures/arms.rst``), and
    ``examples/any_arm.py --robot planar2`` (``figures/any_arm.txt``).
``arms_compliant``
    ``benchmarks/bench_arms.py --compliant --n 6 0 0 --seed 20261701 --jobs 2``:
    planar two-link arms with two-mass joints, half with backlash
    (``figures/arms_compliant.rst``; before the arm path's floor rule,
    :data:`identification.model_choice.ARM_FLOOR_FACTOR`:
    ``figures/bench_arms_compliant_before_floor_rule.txt``; 3.5 min on 2 cores since the arm's lane
    loop vectorises, 6 min before, with the flexible fit's ``leader_stop``,
    about 25 min before it:
    ``figures/bench_arms_compliant_before_leader_stop.txt``; seeds 20261122 to
    20261127 were this benchmark's development draws; ``--n 0 3 0`` adds PUMA
    joints 1-3, about 1.3 min a draw); on the version whose check keeps the
    tied design with the smallest current step (:func:`ctc.flexible.tied_choice`),
    the same command's stdout: ``figures/bench_arms_compliant_tied_design.txt``.
``arms_compliant_puma123``
    ``benchmarks/bench_arms.py --compliant --n 0 2 0 --seed 20261801 --jobs 2``:
    PUMA 560 joints 1-3 with two-mass joints and backlash, two draws of a
    seed declared before looking (``figures/arms_compliant_puma123_20261801.txt``;
    about 1.3 min a draw with its kernels' compile, the two sharing 2 cores;
    before the arm's lane loop vectorised, about 7 min:
    ``figures/arms_compliant_puma123_20261801_before_vectorised.txt``; before the
    flexible fit's ``leader_stop``:
    ``figures/arms_compliant_puma123_20261801_before_leader_stop.txt``; rerun after the
    arm path's floor rule, the same table but the times:
    ``figures/arms_compliant_puma123_20261801_floor_rule.txt``).
``arms_random``
    Robots no one wrote by hand, seeds chosen before looking:
    ``benchmarks/bench_arms.py --n 0 0 0 12 --seed 20262711 --jobs 2`` (chains of
    2-4 joints from random DH tables, standard or modified, on a randomly tilted
    base; ``figures/bench_arms_random_20262711.txt``), ``--n 0 0 0 0 12 --seed
    20262741`` (random URDF chains, pinocchio's dynamics;
    ``figures/bench_arms_urdf_20262741.txt``), ``--n 0 0 0 12 12 --seed 20262791
    --jobs 2`` (a second seed of both; ``figures/bench_arms_random_urdf_20262791.txt``),
    ``--compliant --n 0 0 0 8 --seed
    20262731 --jobs 2`` (the random DH chains with two-mass joints;
    ``figures/bench_arms_random_compliant_20262731.txt`` when rerun: the committed run
    is of the version before the arm path's floor rule,
    :data:`identification.model_choice.ARM_FLOOR_FACTOR`, ``..._20262731_before_floor_rule.txt``;
    its three draws that the rule moves,
    ``--n 0 0 0 2 --seed 20262731`` and ``--n 0 0 0 1 --seed 20262735``, after it:
    ``..._20262731_floor_rule.txt``, ``..._20262735_floor_rule.txt``; before the
    flexible fit's ``leader_stop``:
    ``figures/bench_arms_random_compliant_20262731_before_leader_stop.txt``),
    ``--compliant --n 0 0 0 6 --seed 20262831 --jobs 2`` (a fresh seed of them;
    ``figures/bench_arms_random_compliant_20262831.txt``; before the floor rule:
    ``..._20262831_before_floor_rule.txt``),
    ``benchmarks/bench_arm_floor.py --n 6 6 0 6 6 --seed 20262901 --jobs 2`` (what
    the rigid fit leaves on rigid arms; ``figures/bench_arm_floor_20262901.txt``;
    again, with ``--jobs 1``, after the guessed box's widening:
    ``..._20262901_widening.txt``, the same lines but the times),
    ``bench_arms.py --compliant --n 6 --seed 20262921 --jobs 2`` and ``--compliant
    --n 0 0 0 6 --seed 20262911 --jobs 2`` (fresh seeds of compliant planar arms
    and random DH chains after the floor rule;
    ``figures/bench_arms_compliant_20262921.txt``,
    ``figures/bench_arms_random_compliant_20262911.txt``; before the default
    identification's search restart and the flexible fit's link-model screen at
    ``link_check``'s configurations: ``..._20262921_before_restart.txt``,
    ``..._20262911_before_restart.txt``; before the guessed box's widening, the
    two-mass fit's refit at ``IA_FRACTION_MAX`` and the check's following-error
    limit: ``..._20262911_before_widening.txt``; with the two-mass box at 99.9 % from
    the start, a version not kept: ``..._20262911_wide_first_box.txt``; of the
    planar arms after them: ``figures/bench_arms_compliant_20262921_widening.txt``; draw 20262923 alone, ``--compliant --n 1
    --seed 20262923``, of both versions: ``..._20262923_restart.txt``,
    ``..._20262923_before_restart.txt``), four single draws whose
    lines print each model's held-back floors and paired t, quoted in the tutorial
    (``figures/bench_arms_model_choice_random_20262833.txt``, ``..._random_20262731.txt``,
    ``..._planar2_20262922.txt``, ``..._planar2_20262101.txt``) and
    ``benchmarks/bench_arm_payload.py --n 0 0 6 6 --seed 20262751`` (a payload on
    both kinds; ``figures/bench_arm_payload_random_20262751.txt``; the same before
    the payload search's first-moment stage:
    ``figures/bench_arm_payload_random_20262751_before_first_moments.txt``) and
    ``--seed 20262771``, a fresh draw after it
    (``figures/bench_arm_payload_random_20262771.txt``; the same before the
    wide search: ``..._20262771_before_wide_search.txt``) and ``--seed 20262811
    --jobs 2``, a fresh draw after the wide search
    (``figures/bench_arm_payload_random_20262811.txt``); and
    ``benchmarks/bench_arm_adaptive.py --n 0 0 3 3 --seed 20262781 --jobs 2`` (the
    adaptive CTC through a change on both kinds;
    ``figures/bench_arm_adaptive_random_20262781.txt``; before the quiet
    refinement of :mod:`ctc.arm_adaptive`:
    ``figures/bench_arm_adaptive_random_20262781_before_quiet_refinement.txt``).
``arm_payload``
    ``benchmarks/bench_arm_payload.py --n 8 6 --seed 20261125 --jobs 2``: a
    payload on the last link of planar two-link arms and PUMA joints 1-3
    from 0.2 s windows of the independent simulator's logs, and the CTC
    with it (``figures/bench_arm_payload.txt``; ``figures/bench_arm_payload_stop60.txt``
    is the same run before the payload search's first-moment stage).
``arm_adaptive``
    ``benchmarks/bench_arm_adaptive.py --n 12 8 --seed 20261501 --jobs 2``:
    pick-ups, put-downs, friction changes and no change on planar two-link
    arms and PUMA joints 1-3 of the independent simulator, the static and the
    adaptive CTC of the arm side by side (``figures/bench_arm_adaptive.txt``); then
    ``--n 20 12 --seed 20261601``, a second draw (``figures/bench_arm_adaptive_20261601.txt``).
    Both before the quiet refinement (:mod:`ctc.arm_adaptive`, step 4):
    ``figures/bench_arm_adaptive_before_quiet_refinement.txt`` and
    ``figures/bench_arm_adaptive_20261601_before_quiet_refinement.txt``.
``arm_adaptive_compliant``
    ``benchmarks/bench_arm_adaptive.py --compliant --n 6 2 --seed 20262001 --jobs 2``:
    the same changes on compliant arms (two-mass joints, half with backlash), the
    prior the default identification, flexible priors adapted through their
    two-mass arm (``figures/bench_arm_adaptive_compliant_20262001.txt``); its first
    planar draw rerun after the start-window fix (``--only planar2:20262001``,
    ``figures/bench_arm_adaptive_compliant_20262001_rerun.txt``); its PUMA 1-3 draw
    rerun after the empty gripper stopped being "refined" (``--only puma123:20262001``,
    ``figures/bench_arm_adaptive_compliant_20262001_rerun_puma123.txt``); and a draw of
    payload changes only (``--kinds pick-up,put-down --n 3 0 --seed 20262101 --jobs 2``,
    ``figures/bench_arm_adaptive_compliant_payload_20262101.txt``; its first run, on the
    version before the start-window fix:
    ``figures/bench_arm_adaptive_compliant_payload_20262101_before_start_window.txt``;
    its draw 20262103 on the version before the quiet refinement, the same script at
    commit 7fee51d with ``--only planar2:20262103``:
    ``figures/bench_arm_adaptive_compliant_payload_20262103_at_7fee51d.txt``; its
    first draw, whose prior the floor rule of :data:`identification.model_choice.ARM_FLOOR_FACTOR`
    made flexible, ``--n 1 0``:
    ``figures/bench_arm_adaptive_compliant_payload_20262101_floor_rule.txt``); that
    payload draw rerun whole on the version with the springs' rival (``--jobs 1``,
    ``figures/bench_arm_adaptive_compliant_payload_20262101_springs_rival.txt``), and its
    draws 20262102 and 20262103 alone (``--only planar2:20262102``, ``--only
    planar2:20262103``) by the same script at commit 5926562 with the benchmark's new
    kinds copied in (``figures/bench_arm_adaptive_compliant_payload_20262102_at_5926562.txt``,
    ``..._20262103_at_5926562.txt``); and that payload draw rerun whole (``--jobs 1``) on
    the version whose two-mass windows start in the wider box of
    :mod:`identification.arm_payload` and whose return to the empty gripper is not held
    (:mod:`ctc.arm_adaptive`, step 3):
    ``figures/bench_arm_adaptive_compliant_payload_20262101_return_to_prior.txt``, with
    ``--json`` its windows' decisions (``..._20262101_return_to_prior.json``); and its
    draw 20262103 alone on the version before (commit b895508, ``--only planar2:20262103
    --json``): ``figures/bench_arm_adaptive_compliant_payload_20262103_at_b895508.json``.
    A fresh draw on a seed chosen before its run, ``--compliant --n 6 0 --seed 20261831``
    (every kind of change), on this version and at commit b895508 side by side
    (``figures/bench_arm_adaptive_compliant_20261831.txt``,
    ``..._20261831_at_b895508.txt``; this version's ``--json`` record:
    ``..._20261831.json``); and a second, payload changes only, ``--compliant --kinds
    pick-up,put-down --n 6 0 --seed 20261841``, likewise
    (``figures/bench_arm_adaptive_compliant_payload_20261841.txt``,
    ``..._20261841_at_b895508.txt``, and both ``--json`` records, ``.json``).
    With the feedback held (a rigid-equivalent design's adaptive CTC) and the return to
    the prior from a window it does not describe, both draws and the payload draw rerun
    with ``--json`` (``figures/bench_arm_adaptive_compliant_20261831_held_feedback.txt``,
    ``figures/bench_arm_adaptive_compliant_payload_20261841_held_feedback.txt``,
    ``figures/bench_arm_adaptive_compliant_payload_20262101_held_feedback.txt``, each
    with its ``.json``), the development draw ``--compliant --n 6 0 --seed 20261901
    --only planar2:20261902 --json``
    (``figures/bench_arm_adaptive_compliant_20261902_held_feedback.txt``, ``.json``),
    and a fresh draw on a seed chosen before its run, ``--compliant --kinds
    pick-up,put-down --n 6 0 --seed 20261861 --json``
    (``figures/bench_arm_adaptive_compliant_payload_20261861.txt``, ``.json``), whose
    two draws that differ were rerun on the version before (``--only
    planar2:20261863``, ``--only planar2:20261866``, at 84efcc3:
    ``figures/bench_arm_adaptive_compliant_payload_20261863_at_84efcc3.txt``,
    ``..._20261866_at_84efcc3.txt``, each with its ``.json``); a fourth fresh draw,
    ``--compliant --n 6 0 --seed 20261871 --jobs 2 --json``
    (``figures/bench_arm_adaptive_compliant_20261871.txt``, ``.json``), its miss rerun on
    the version before (``--only planar2:20261873``:
    ``figures/bench_arm_adaptive_compliant_20261873_at_84efcc3.txt``, ``.json``).
    With the hand-over of the window's link state to a flexible-joint CTC
    (:mod:`ctc.arm_adaptive`): the fourth draw rerun, ``--compliant --n 6 0 --seed
    20261871 --jobs 2 --json`` (``figures/bench_arm_adaptive_compliant_20261871_handover.txt``,
    ``.json``), its draw 20261873 alone with the hand-over's record (``--only
    planar2:20261873 --json``: ``figures/bench_arm_adaptive_compliant_20261873_handover.txt``,
    ``.json``), the third rerun, ``--compliant --kinds pick-up,put-down --n 6 0 --seed
    20261861 --jobs 2 --json`` (``figures/bench_arm_adaptive_compliant_payload_20261861_handover.txt``,
    ``.json``), and a fifth fresh draw on a seed chosen before its run, ``--compliant --kinds
    pick-up,put-down --n 6 0 --seed 20261881 --jobs 2 --json``
    (``figures/bench_arm_adaptive_compliant_payload_20261881.txt``, ``.json``), its draw
    20261885 rerun on the version before (``--only planar2:20261885 --json`` at 6b70524:
    ``figures/bench_arm_adaptive_compliant_payload_20261885_at_6b70524.txt``, ``.json``);
    a sixth fresh draw, every kind, ``--compliant --n 6 0 --seed 20261891 --jobs 2 --json``
    (``figures/bench_arm_adaptive_compliant_20261891.txt``, ``.json``; printed before the
    benchmark scored a carried tool's models before a put-down), its draw 20261892 rerun
    on the version before (``--only planar2:20261892 --json`` at 6b70524:
    ``figures/bench_arm_adaptive_compliant_20261892_at_6b70524.txt``, ``.json``).
    With the second opinion (:mod:`ctc.arm_adaptive`, step 3): the sixth draw rerun,
    ``--compliant --n 6 0 --seed 20261891 --jobs 2 --json``
    (``figures/bench_arm_adaptive_compliant_20261891_second_opinion.txt``, ``.json``), the
    third and the second, ``--compliant --kinds pick-up,put-down --n 6 0 --seed 20261861``
    and ``--seed 20261841`` (``--jobs 2 --json``;
    ``figures/bench_arm_adaptive_compliant_payload_20261861_second_opinion.txt``,
    ``..._payload_20261841_second_opinion.txt``, each with its ``.json``), and a seventh
    fresh draw on a seed chosen before its run, every kind, ``--compliant --n 6 0 --seed
    20261911 --jobs 2 --json`` (``figures/bench_arm_adaptive_compliant_20261911.txt``,
    ``.json``); the fourth draw on that version, ``--compliant --n 6 0 --seed 20261871
    --jobs 2 --json`` (``figures/bench_arm_adaptive_compliant_20261871_second_opinion.txt``,
    ``.json``).  With the link start box widened where a fit sits at its edge
    (:mod:`identification.arm_payload`), before the divergence guard: the runs of seeds
    20261871 and 20261861 (``figures/bench_arm_adaptive_compliant_20261871_ringing.txt``,
    ``..._payload_20261861_ringing.txt``, each with its ``.json``) and an eighth fresh
    draw on a seed chosen before its run, every kind, ``--compliant --n 6 0 --seed 20261921
    --jobs 2 --json`` (``figures/bench_arm_adaptive_compliant_20261921_before_guard.txt``,
    ``.json``), its draw 20261926 at a06fa66 (``--only planar2:20261926 --json``:
    ``figures/bench_arm_adaptive_compliant_20261926_at_a06fa66.txt``, ``.json``); with the
    divergence guard of :mod:`ctc.arm_adaptive`, the eighth draw again
    (``figures/bench_arm_adaptive_compliant_20261921.txt``, ``.json``); the deflections that motivate the box's widening,
    ``benchmarks/bench_spring_deflection.py --seeds 20261841 20261861 20261871 20261881
    20261891 --n 6`` (``figures/bench_spring_deflection.txt``).
``arm_adaptive_drive``
    ``benchmarks/bench_arm_adaptive.py --compliant --kinds stiffness,damping --n 3
    --seed 20261381``: compliant planar arms whose springs change (every joint's
    stiffness x0.7 or damping x2; seed chosen before looking; the PUMA 1-3 draws, at
    16 s per window, did not fit the stop that ran it), on the version with the springs'
    rival of :mod:`ctc.arm_adaptive` (``figures/bench_arm_adaptive_drive_changes_20261381.txt``)
    and, the same script at commit 5926562 (the version before it), with the benchmark's
    new kinds copied in (``figures/bench_arm_adaptive_drive_changes_20261381_before_springs_rival.txt``);
    then the next three planar draws of the seed, ``--n 6 --only
    planar2:20261384,planar2:20261385,planar2:20261386``, on both versions
    (``figures/bench_arm_adaptive_drive_changes_20261381_draws_4_6.txt``,
    ``..._draws_4_6_before_springs_rival.txt``); and its first PUMA 1-3 draw on this
    version, ``--n 0 2 --only puma123:20261381``
    (``figures/bench_arm_adaptive_drive_changes_20261381_puma123_1.txt``).  The six
    planar draws, ``--n 6 0``, on the version with the wider start box of the two-mass
    windows (:mod:`identification.arm_payload`)
    (``figures/bench_arm_adaptive_drive_changes_20261381_start_box.txt``; the return to
    the empty gripper, which came with it, does not act on these draws: no payload is
    ever in use).  The first three draws, ``--n 3 0 --json``, with the second opinion
    (``figures/bench_arm_adaptive_drive_changes_20261381_second_opinion.txt``, ``.json``).
``arm_excitation``
    ``benchmarks/bench_arm_excitation.py --n 4 4 0 --seed 20262611 --jobs 2``: the
    excitation design for any arm (``design_excitation(..., model=)``) against each
    draw's own multisine, within its envelope, on the independent simulator
    (``figures/bench_arm_excitation_20262611.txt``); then one six-joint draw
    (``--n 0 0 1``, ``figures/bench_arm_excitation_puma6_20262611.txt``); a
    second draw, ``--seed 20262621`` (``figures/bench_arm_excitation_20262621.txt``);
    and a third, ``--seed 20262631`` (``figures/bench_arm_excitation_20262631.txt``).
    The ``*_stop59.txt`` files are the same runs of the design before its repair
    pulled offsets towards the start state and before the SLSQP polish (commit
    ``93c40ba``).

Run from the repository root (kernels compiled once before; numba threads as
for the quoted figures)::

    python docs/make_figures.py
    python docs/make_figures.py --sections identification,ctc
    python docs/make_figures.py --quick            # smoke run of the script itself

``--quick`` runs every section with small settings (seconds to a minute);
its figures are not the quoted ones, so it writes to ``--out`` (default
``out/figures``) unless ``--out docs`` is given explicitly.
"""
from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
DATA = REPO / "tests" / "data"
SECTIONS = ("simulator", "identification", "timings", "alteration", "ctc", "real_rigs", "speed",
            "optimisers", "flexible", "methods", "coverage", "excitation", "online_payload",
            "robustness", "changes", "changes_updates", "changes_reported", "changes_third",
            "changes_fourth", "current_cap", "changes_inconsistent", "changes_fifth",
            "changes_fallback", "changes_sixth", "changes_seventh",
            "arms", "arms_compliant", "arms_compliant_puma123", "arms_random", "arm_payload",
            "arm_adaptive",
            "arm_adaptive_compliant", "arm_adaptive_drive", "arm_excitation")
WELL_EXCITED = (0, 1, 3, 5, 6, 8)  # f1 f2 f4 f6 f7 f9


def _truth(stem):
    return np.asarray(json.loads((DATA / f"{stem}.truth.json").read_text())["f_vector"])


def _rel_pct(f, f_true):
    return [float(v) for v in 100.0 * (np.asarray(f) - f_true) / np.abs(f_true)]


def _env():
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(REPO)] + [p for p in
                                         env.get("PYTHONPATH", "").split(os.pathsep) if p])
    env["MPLBACKEND"] = "Agg"
    env["PUMA_DATA_DIR"] = str(DATA)  # the benchmarks read the truth files from here
    return env


def _run(args, raw_dir, name, timeout=3600):
    """Run a script of the repository; its stdout is kept as ``raw_dir/name.txt``."""
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, *map(str, args)], cwd=REPO, env=_env(),
                          capture_output=True, text=True, timeout=timeout)
    (raw_dir / f"{name}.txt").write_text(proc.stdout)
    if proc.returncode != 0:
        tail = proc.stderr.strip().splitlines()[-1:] or ["(no message)"]
        raise RuntimeError(f"{' '.join(map(str, args))} exited {proc.returncode}: {tail[0]}")
    return proc.stdout, time.perf_counter() - t0


# ---------------------------------------------------------------------------- sections
def simulator(ctx):
    import plant

    out = {"substeps": plant.DEFAULT_SUBSTEPS}
    for stem in ("puma560_paper_rigid", "puma560_validation_rigid"):
        log = plant.load_log(DATA / f"{stem}.csv")
        e = plant.simulate_experiment(log, _truth(stem))
        d = np.abs(e - log.e_pulses)
        out[stem] = {"identical_pct": float(100 * np.mean(np.all(d == 0, axis=1))),
                     "within_1_pulse_pct": float(100 * np.mean(np.all(d <= 1, axis=1))),
                     "max_abs_diff_pulses": int(d.max())}
    return out


def identification(ctx):
    import identification as ident
    import plant

    log = plant.load_example()
    f_true = _truth("puma560_paper_rigid")
    val = plant.load_log(DATA / "puma560_validation_rigid.csv")
    out = {"log": log.name}
    for method in ident.METHODS:
        res = ident.identify(log, method=method, rng=0, progress=False, **ctx["quick"])
        if method == ident.DEFAULT_METHOD:
            # the two plots the identification tutorial explains
            res.plot().savefig(ctx["images"] / "identification_convergence.png", dpi=110)
            res.plot_tracking_errors().savefig(ctx["images"] / "identification_tracking_errors.png",
                                               dpi=110)
        err = _rel_pct(res.f, f_true)
        e_val = plant.simulate_experiment(val, res.f)
        out[method] = {
            "f": [float(v) for v in res.f], "error_pct": err,
            "max_abs_error_well_excited_pct": max(abs(err[i]) for i in WELL_EXCITED),
            "objective_pulses2": float(res.fun), "evaluations": int(res.nfev),
            "wall_time_s": float(res.wall_time_s),
            "ga_final_best_pulses2": float(res.history["best"][-1]),
            "validation_output_error_pulses2": float(np.sum((val.e_pulses - e_val) ** 2)),
            "validation_max_abs_diff_pulses": int(np.abs(val.e_pulses - e_val).max()),
        }
    if not ctx["quick"]:
        args = ["-m", "identification", "--example", "--quiet",
                "--output", ctx["raw"] / "cli_example.json"]
        _, wall = _run(args, ctx["raw"], "cli_example")
        out["cli_example_wall_s_incl_start"] = wall
    return out


def timings(ctx):
    """The times the README, the CLI and the examples quote, measured here.

    The README's main command with an empty numba cache (first run: compile)
    and with the cache filled (later runs), each a fresh process; the same
    for the any-arm example on the planar arm, rigid and with flexible
    joints (its robot's generated kernels: :mod:`plant.simulation.generated`,
    under ``$NUMBA_CACHE_DIR/generated``).
    """
    import tempfile

    jobs = {"": ["-m", "identification", "--example", "--quiet"]}
    if not ctx["quick"]:
        jobs["any_arm_planar2_"] = ["examples/any_arm.py", "--robot", "planar2", "--quick"]
        jobs["any_arm_planar2_flexible_"] = [*jobs["any_arm_planar2_"], "--flexible"]
    out = {}
    for prefix, args in jobs.items():
        with tempfile.TemporaryDirectory() as cache:
            env = _env()
            env["NUMBA_CACHE_DIR"] = cache
            env.pop("PUMA_GA_CTC_KERNELS", None)
            extra = ["--out", str(Path(cache) / "out")] if prefix else []
            for name in ("first_run_compile_s", "later_run_cached_s"):
                t0 = time.perf_counter()
                proc = subprocess.run([sys.executable, *args, *extra], cwd=REPO, env=env,
                                      capture_output=True, text=True, timeout=1200)
                if proc.returncode != 0:
                    raise RuntimeError(f"{' '.join(args)} exited {proc.returncode}")
                out[prefix + name] = time.perf_counter() - t0
    return out


def alteration(ctx):
    q = ["--quick"] if ctx["quick"] else ["--seeds", "10"]
    _, wall = _run(["examples/alteration_study.py", *q, "--truth", DATA / "puma560_paper_rigid.truth.json",
          "--validate", DATA / "puma560_validation_rigid.csv", "--out", ctx["raw"] / "alteration"],
         ctx["raw"], "alteration_study")
    rep = json.loads((ctx["raw"] / "alteration" / "alteration.json").read_text())
    out = {"seeds": rep["seeds"], "validation_pulses2_at_truth": rep.get("validation_pulses2_at_truth"),
           "example_wall_s": wall}
    for method, m in rep["methods"].items():
        s = m["statistics"]
        runs = m["runs"]
        out[method] = {
            "alteration_pct": s["alteration_pct"], "error_of_mean_pct": s.get("error_of_mean_pct"),
            "max_abs_error_pct": s.get("max_abs_error_pct"),
            "objective_pulses2_range": [min(r["objective_pulses2"] for r in runs),
                                        max(r["objective_pulses2"] for r in runs)],
            "wall_time_s_mean": float(np.mean([r["wall_time_s"] for r in runs])),
        }
    return out


def ctc(ctx):
    q = ["--quick"] if ctx["quick"] else []
    _, wall = _run(["examples/ctc_vs_p.py", *q, "--truth", DATA / "puma560_paper_rigid.truth.json",
                    "--drill-truth", DATA / "puma560_paper_drill_flex.truth.json",
                    "--out", ctx["raw"] / "ctc_vs_p"], ctx["raw"], "ctc_vs_p")
    res = json.loads((ctx["raw"] / "ctc_vs_p" / "results.json").read_text())
    # the default run (no --truth) identifies f first: its time is the one the docs quote
    _, wall_default = _run(["examples/ctc_vs_p.py", *q, "--out", ctx["raw"] / "ctc_vs_p_default"],
                           ctx["raw"], "ctc_vs_p_default")
    return {"rigid": {r["name"]: r for r in res["rigid"]}, "robustness": res["robustness"],
            "flexible": {r["name"]: r for r in res["flexible"]["rows"]},
            "substeps": res["substeps"], "gains": res["gains"], "example_wall_s": wall,
            "example_default_wall_s": wall_default}


def real_rigs(ctx):
    q = ["--quick"] if ctx["quick"] else []
    _, wall = _run(["examples/real_rigs.py", *q, "--truth",
                    DATA / "puma560_paper_drill_flex.truth.json",
                    "--out", ctx["raw"] / "real_rigs"], ctx["raw"], "real_rigs")
    res = json.loads((ctx["raw"] / "real_rigs" / "results.json").read_text())
    res["example_wall_s"] = wall
    f_true = _truth("puma560_paper_drill_flex")
    for key in [k for k in res if k.startswith("drill_f_")]:
        res[key.replace("drill_f_", "drill_error_pct_")] = _rel_pct(res[key], f_true)
    shutil.copyfile(ctx["raw"] / "real_rigs" / "spectrum.png", ctx["images"] / "real_rigs_spectrum.png")
    return res


def speed(ctx):
    q = ["--quick"] if ctx["quick"] else []
    text, wall = _run(["benchmarks/bench_simulate.py", *q, "--plot", ctx["images"] / "scaling.png"],
                      ctx["raw"], "bench_simulate")
    return {"printed": text.splitlines(), "wall_s": wall}


def optimisers(ctx):
    q = ["--seeds", "0", "--methods", "paper", "ga+pem"] if ctx["quick"] else []
    _run(["benchmarks/bench_optimisers.py", *q, "--out", ctx["raw"] / "bench_optimisers.json",
          "--plot", ctx["images"] / "optimisers_convergence.png"], ctx["raw"], "bench_optimisers")
    return json.loads((ctx["raw"] / "bench_optimisers.json").read_text())


def flexible(ctx):
    q = ["--quick"] if ctx["quick"] else ["--drill"]
    text, wall = _run(["benchmarks/bench_flexible.py", *q, "--json", ctx["raw"] / "bench_flexible.json"],
                      ctx["raw"], "bench_flexible")
    return {"printed": text.splitlines(), "wall_s": wall}


def robustness(ctx):
    q = ["--n", "4"] if ctx["quick"] else ["--n", "106"]
    text, wall = _run(["benchmarks/bench_robustness.py", *q, "--seed", "20261122", "--jobs", "2",
                       "--rst", ctx["raw"] / "robustness.rst"], ctx["raw"], "bench_robustness")
    return {"printed": text.splitlines()[-40:], "wall_s": wall}


def methods(ctx):
    q = ["--quick"] if ctx["quick"] else []
    text, wall = _run(["benchmarks/bench_methods.py", *q, "--out", ctx["raw"] / "bench_methods.json",
                       "--rst", ctx["raw"] / "methods_table.rst"], ctx["raw"], "bench_methods")
    return {"printed": text.splitlines(), "wall_s": wall}


def coverage(ctx):
    q = ["--quick"] if ctx["quick"] else []
    text, wall = _run(["benchmarks/bench_coverage.py", *q, "--out", ctx["raw"] / "bench_coverage.json"],
                      ctx["raw"], "bench_coverage")
    return {"printed": text.splitlines(), "wall_s": wall}


def excitation(ctx):
    q = [] if ctx["quick"] else ["--agreement", "12"]
    text, wall = _run(["benchmarks/bench_excitation.py", *q, "--out", ctx["raw"] / "bench_excitation.json"],
                      ctx["raw"], "bench_excitation")
    return {"printed": text.splitlines(), "wall_s": wall}


def online_payload(ctx):
    text, wall = _run(["benchmarks/bench_online_payload.py"], ctx["raw"], "bench_online_payload")
    q = ["--quick"] if ctx["quick"] else []
    _, wall_ex = _run(["examples/online_payload.py", *q, "--truth",
                       DATA / "puma560_paper_rigid.truth.json", "--out", ctx["raw"] / "online_payload"],
                      ctx["raw"], "online_payload")
    shutil.copyfile(ctx["raw"] / "online_payload" / "errors.png",
                    ctx["images"] / "online_payload_errors.png")
    return {"printed": text.splitlines(), "wall_s": wall, "example_wall_s": wall_ex}


def changes(ctx):
    q = ["--n", "4"] if ctx["quick"] else ["--n", "60"]
    text, wall = _run(["benchmarks/bench_changes.py", *q, "--seed", "20261122", "--jobs", "2",
                       "--rst", ctx["raw"] / "changes.rst"], ctx["raw"], "bench_changes")
    return {"printed": text.splitlines()[-30:], "wall_s": wall}


#: The cases of ``changes`` (seed 20261122) in which the adaptive CTC installed a model
#: (an ``'update'`` event in ``figures/changes.txt``), flexible then rigid robots: the
#: supervisor's pooling acts at an update only, so a change to it is rerun on these.
CHANGES_UPDATE_CASES = {
    "flexible": "5,6,7,9,15,18,29,30,31,36,37,38,41,46,49,54,55,57",
    "rigid": "2,3,4,11,16,17,20,24,25,26,27,34,39,42,48,50,58",
}


def _bench_changes(ctx, name, seed, cases=None, n=60, fresh=False, extra=(), own_logs=False):
    """``benchmarks/bench_changes.py`` on ``cases`` (comma-separated) or its first ``n``
    draws of ``seed``; ``fresh``: in a new output folder (no case or prior cached by
    another version is reused); ``own_logs``: the robustness suite's logs and
    identifications in a new folder too (every prior identified by this version).
    Returns the section's record."""
    import tempfile

    args = ["benchmarks/bench_changes.py", "--n", str(n), "--seed", str(seed), "--jobs", "2",
            "--rst", ctx["raw"] / f"{name}.rst", *extra]
    if cases is not None:
        args += ["--cases", cases.split(",")[0] if ctx["quick"] else cases]
    if not fresh:
        text, wall = _run(args, ctx["raw"], name, timeout=3 * 3600)
    else:
        with tempfile.TemporaryDirectory() as tmp:
            if own_logs:
                args += ["--robust-out", str(Path(tmp) / "robustness")]
            text, wall = _run(args + ["--out", tmp], ctx["raw"], f"{name}_run", timeout=3 * 3600)
    return {"printed": text.splitlines()[-30:], "wall_s": wall}


def changes_updates(ctx):
    return {joints: _bench_changes(ctx, f"changes_updates_{joints}", 20261122, cases)
            for joints, cases in CHANGES_UPDATE_CASES.items()}


#: The cases of each draw of the changes benchmark with an ``'unexplained'`` event and an
#: ``'update'`` event (``figures/changes.txt``, ``figures/changes_fresh.txt``): the supervisor's
#: hold after a reported change (:mod:`ctc.adaptive`, step 5) needs a reported change
#: before an update, so every other case is unchanged by it bit for bit.
CHANGES_REPORTED_CASES = {20261122: "4,5,17,24,31,37", 20261123: "6,12,21,33"}


def changes_reported(ctx):
    return {str(seed): _bench_changes(ctx, f"changes_reported_{seed}", seed, cases, fresh=True)
            for seed, cases in CHANGES_REPORTED_CASES.items()}


def changes_third(ctx):
    return _bench_changes(ctx, "changes_20261126", 20261126, n=2 if ctx["quick"] else 24,
                          fresh=True)


def changes_fourth(ctx):
    return _bench_changes(ctx, "changes_20261130", 20261130, n=2 if ctx["quick"] else 58,
                          fresh=True)


#: The cases of the fourth draw (seed 20261130) with an ``'unexplained'`` event and an
#: ``'update'`` event (``figures/changes_20261130.txt``): an inconsistent episode needs
#: updates before it and reports the change, so only these can be moved by the rule that
#: agreeing estimates describing their windows end its pause (:mod:`ctc.adaptive`, step 5).
FOURTH_REPORTED_UPDATE_CASES = "9,21,36,55"


def changes_inconsistent(ctx):
    """The fourth draw's cases an inconsistent pause can touch, every prior identified anew."""
    return _bench_changes(ctx, "changes_inconsistent_20261130", 20261130,
                          FOURTH_REPORTED_UPDATE_CASES, n=58, fresh=True, own_logs=True)


def changes_fifth(ctx):
    """A fifth draw of the changes benchmark, seed chosen before its first run."""
    return _bench_changes(ctx, "changes_20261271", 20261271, n=2 if ctx["quick"] else 58,
                          fresh=True, own_logs=True)


#: The cases of the fifth and sixth draws whose adaptive CTC fell back to the P law
#: (``figures/changes_20261271.txt``, ``figures/changes_20261327.txt``): the diagnosis of
#: the P law's windows (:mod:`ctc.adaptive`, step 6) acts after a fallback only, so every
#: other case is unchanged by it bit for bit.
FALLBACK_CASES = {20261271: "3,8,9,23", 20261327: "2,21,25"}


def changes_fallback(ctx):
    """The draws' fallbacks with the P law's windows diagnosed, every prior identified anew."""
    return {str(seed): _bench_changes(ctx, f"changes_fallback_{seed}", seed, cases, n=58,
                                      fresh=True, own_logs=True)
            for seed, cases in FALLBACK_CASES.items()}


def changes_sixth(ctx):
    """A sixth draw of the changes benchmark, seed chosen before its first run."""
    return _bench_changes(ctx, "changes_20261327", 20261327, n=2 if ctx["quick"] else 58,
                          fresh=True, own_logs=True)


def changes_seventh(ctx):
    """A seventh draw of the changes benchmark, seed chosen before its first run."""
    return _bench_changes(ctx, "changes_20261329", 20261329, n=2 if ctx["quick"] else 58,
                          fresh=True, own_logs=True)


#: The flexible payload changes of the fourth draw of the changes benchmark (seed 20261130):
#: every pick-up and put-down on a flexible robot, none chosen by its outcome.
FOURTH_FLEXIBLE_PAYLOAD_CASES = "1,2,4,5,8,11,16,19,22,28,33,34,44,47,49,50,55,56"

#: The flexible payload changes among the first 70 draws of the seed 20261328 (chosen before
#: their run): every pick-up and put-down on a flexible robot.
TIE_FLEXIBLE_PAYLOAD_CASES = "6,16,17,29,31,37,50,55,57,58,66,68"


def current_cap(ctx):
    """The robust flexible design's one-pulse current step and what capping it costs."""
    cases = "2" if ctx["quick"] else FOURTH_FLEXIBLE_PAYLOAD_CASES
    text, wall = _run(["benchmarks/bench_design_current.py", "--seed", "20261130", "--cases", cases],
                      ctx["raw"], "design_current_20261130", timeout=3 * 3600)
    capped = _bench_changes(ctx, "changes_20261130_cap01", 20261130, n=2 if ctx["quick"] else 58,
                            fresh=True, extra=("--max-current-per-pulse", "0.1"))
    tie_cases = "6" if ctx["quick"] else TIE_FLEXIBLE_PAYLOAD_CASES
    tie, tie_wall = _run(["benchmarks/bench_design_current.py", "--seed", "20261328", "--designs",
                          "from_result,tie0", "--cases", tie_cases, "--jobs", "2"],
                         ctx["raw"], "design_current_20261328", timeout=3 * 3600)
    return {"printed": text.splitlines(), "wall_s": wall, "capped": capped,
            "tie_printed": tie.splitlines(), "tie_wall_s": tie_wall}


def arms(ctx):
    q = ["--n", "1", "1", "1"] if ctx["quick"] else ["--n", "10", "8", "6"]
    text, wall = _run(["benchmarks/bench_arms.py", *q, "--seed", "20261122",
                       "--rst", ctx["raw"] / "arms.rst"], ctx["raw"], "bench_arms")
    # relative --out: the printed paths do not depend on where the repository is
    ex, wall_ex = _run(["examples/any_arm.py", "--robot", "planar2", "--out", "out/any_arm"],
                       ctx["raw"], "any_arm")
    return {"printed": text.splitlines()[-20:], "wall_s": wall, "example": ex.splitlines(),
            "example_wall_s": wall_ex}


def arms_compliant(ctx):
    q = ["--n", "1", "1", "0"] if ctx["quick"] else ["--n", "6", "0", "0", "--jobs", "2"]
    text, wall = _run(["benchmarks/bench_arms.py", "--compliant", *q, "--seed", "20261701",
                       "--rst", ctx["raw"] / "arms_compliant.rst"], ctx["raw"], "bench_arms_compliant",
                      timeout=3 * 3600)
    return {"printed": text.splitlines()[-20:], "wall_s": wall}


def arms_compliant_puma123(ctx):
    q = ["--n", "0", "1", "0"] if ctx["quick"] else ["--n", "0", "2", "0", "--jobs", "2"]
    text, wall = _run(["benchmarks/bench_arms.py", "--compliant", *q, "--seed", "20261801"],
                      ctx["raw"], "arms_compliant_puma123_20261801", timeout=3 * 3600)
    return {"printed": text.splitlines()[-10:], "wall_s": wall}


def arms_random(ctx):
    runs = ((["benchmarks/bench_arms.py", "--n", "0", "0", "0", "12", "--seed", "20262711",
              "--jobs", "2"], "bench_arms_random_20262711"),
            (["benchmarks/bench_arms.py", "--n", "0", "0", "0", "0", "12", "--seed", "20262741"],
             "bench_arms_urdf_20262741"),
            (["benchmarks/bench_arms.py", "--n", "0", "0", "0", "12", "12", "--seed", "20262791",
              "--jobs", "2"], "bench_arms_random_urdf_20262791"),
            (["benchmarks/bench_arms.py", "--compliant", "--n", "0", "0", "0", "8", "--seed",
              "20262731", "--jobs", "2"], "bench_arms_random_compliant_20262731"),
            (["benchmarks/bench_arms.py", "--compliant", "--n", "0", "0", "0", "6", "--seed",
              "20262831", "--jobs", "2"], "bench_arms_random_compliant_20262831"),
            (["benchmarks/bench_arms.py", "--compliant", "--n", "0", "0", "0", "2", "--seed",
              "20262731", "--jobs", "2"], "bench_arms_random_compliant_20262731_floor_rule"),
            (["benchmarks/bench_arms.py", "--compliant", "--n", "0", "0", "0", "1", "--seed",
              "20262735"], "bench_arms_random_compliant_20262735_floor_rule"),
            *((["benchmarks/bench_arms.py", "--compliant", "--n", *counts, "--seed", seed],
               f"bench_arms_model_choice_{family}_{seed}")
              for family, counts, seed in (("random", ("0", "0", "0", "1"), "20262833"),
                                           ("random", ("0", "0", "0", "1"), "20262731"),
                                           ("planar2", ("1",), "20262922"),
                                           ("planar2", ("1",), "20262101"))),
            (["benchmarks/bench_arm_floor.py", "--n", "6", "6", "0", "6", "6", "--seed", "20262901",
              "--jobs", "2"], "bench_arm_floor_20262901"),
            (["benchmarks/bench_arms.py", "--compliant", "--n", "6", "--seed", "20262921",
              "--jobs", "2"], "bench_arms_compliant_20262921"),
            (["benchmarks/bench_arms.py", "--compliant", "--n", "0", "0", "0", "6", "--seed",
              "20262911", "--jobs", "2"], "bench_arms_random_compliant_20262911"),
            (["benchmarks/bench_arm_payload.py", "--n", "0", "0", "6", "6", "--seed", "20262751"],
             "bench_arm_payload_random_20262751"),
            (["benchmarks/bench_arm_payload.py", "--n", "0", "0", "6", "6", "--seed", "20262771"],
             "bench_arm_payload_random_20262771"),
            (["benchmarks/bench_arm_payload.py", "--n", "0", "0", "6", "6", "--seed", "20262811",
              "--jobs", "2"], "bench_arm_payload_random_20262811"),
            (["benchmarks/bench_arm_adaptive.py", "--n", "0", "0", "3", "3", "--seed", "20262781",
              "--jobs", "2"], "bench_arm_adaptive_random_20262781"))
    if ctx["quick"]:
        runs = ((["benchmarks/bench_arms.py", "--n", "0", "0", "0", "1", "1", "--seed", "20262711"],
                 "bench_arms_random_20262711"),)
    out = {}
    for args, name in runs:
        text, wall = _run(args, ctx["raw"], name, timeout=4 * 3600)
        out[name] = {"printed": text.splitlines()[-12:], "wall_s": wall}
    return out


def arm_payload(ctx):
    q = ["--n", "1", "0", "--windows", "1", "--ctc-s", "1.0"] if ctx["quick"] else \
        ["--n", "8", "6", "--jobs", "2"]
    text, wall = _run(["benchmarks/bench_arm_payload.py", *q, "--seed", "20261125"], ctx["raw"],
                      "bench_arm_payload", timeout=2 * 3600)
    return {"printed": text.splitlines()[-12:], "wall_s": wall}


def arm_adaptive(ctx):
    out = {}
    # the quoted draw, then a second, larger one (both seeds chosen before looking)
    for seed, n, name in (("20261501", ("12", "8"), "bench_arm_adaptive"),
                          ("20261601", ("20", "12"), "bench_arm_adaptive_20261601")):
        q = ["--n", "1", "0", "--run-s", "2.6"] if ctx["quick"] else ["--n", *n, "--jobs", "2"]
        text, wall = _run(["benchmarks/bench_arm_adaptive.py", *q, "--seed", seed], ctx["raw"],
                          name, timeout=2 * 3600)
        out[seed] = {"printed": text.splitlines()[-18:], "wall_s": wall}
        if ctx["quick"]:
            break
    return out


def arm_adaptive_compliant(ctx):
    # compliant arms, a seed chosen before looking (20261901 served development)
    q = ["--n", "1", "0", "--run-s", "2.6"] if ctx["quick"] else ["--n", "6", "2", "--jobs", "2"]
    out = {}
    runs = (("20262001", q, "bench_arm_adaptive_compliant_20262001"),
            ("20262001", ["--n", "6", "2", "--only", "planar2:20262001"],
             "bench_arm_adaptive_compliant_20262001_rerun"),
            ("20262001", ["--n", "6", "2", "--only", "puma123:20262001"],
             "bench_arm_adaptive_compliant_20262001_rerun_puma123"),
            ("20262101", ["--kinds", "pick-up,put-down", "--n", "3", "0", "--jobs", "2"],
             "bench_arm_adaptive_compliant_payload_20262101"),
            ("20262101", ["--kinds", "pick-up,put-down", "--n", "1", "0"],
             "bench_arm_adaptive_compliant_payload_20262101_floor_rule"))
    for seed, args, name in runs[:1] if ctx["quick"] else runs:
        text, wall = _run(["benchmarks/bench_arm_adaptive.py", "--compliant", *args, "--seed", seed],
                          ctx["raw"], name, timeout=3 * 3600)
        out[name] = {"printed": text.splitlines()[-18:], "wall_s": wall}
    return out


def arm_adaptive_drive(ctx):
    # compliant arms whose springs change (seed chosen before looking)
    q = ["--n", "1", "--run-s", "2.6"] if ctx["quick"] else ["--n", "3"]
    out = {}
    runs = ((q, "bench_arm_adaptive_drive_changes_20261381"),
            (["--n", "6", "--only", "planar2:20261384,planar2:20261385,planar2:20261386"],
             "bench_arm_adaptive_drive_changes_20261381_draws_4_6"))
    for args, name in runs[:1] if ctx["quick"] else runs:
        text, wall = _run(["benchmarks/bench_arm_adaptive.py", "--compliant", "--kinds",
                           "stiffness,damping", *args, "--seed", "20261381"], ctx["raw"], name,
                          timeout=3 * 3600)
        out[name] = {"printed": text.splitlines()[-20:], "wall_s": wall}
    return out


def arm_excitation(ctx):
    # a seed chosen before looking (20262601 served development); then one six-joint draw
    out = {}
    runs = ((["--n", "4", "4", "0", "--jobs", "2"], "bench_arm_excitation_20262611"),
            (["--n", "0", "0", "1"], "bench_arm_excitation_puma6_20262611"),
            (["--n", "4", "4", "0", "--jobs", "2", "--seed", "20262621"],
             "bench_arm_excitation_20262621"),
            (["--n", "4", "4", "0", "--jobs", "2", "--seed", "20262631"],
             "bench_arm_excitation_20262631"))
    if ctx["quick"]:
        runs = ((["--n", "1", "0", "0", "--generations", "4"], "bench_arm_excitation_20262611"),)
    for args, name in runs:
        seed = [] if "--seed" in args else ["--seed", "20262611"]
        text, wall = _run(["benchmarks/bench_arm_excitation.py", *args, *seed],
                          ctx["raw"], name, timeout=2 * 3600)
        out[name] = {"printed": text.splitlines()[-12:], "wall_s": wall}
    return out


# -------------------------------------------------------------------------------- main
def _commit():
    try:
        return subprocess.run(["git", "rev-parse", "HEAD"], cwd=REPO, capture_output=True,
                              text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return None


def _write_json_atomic(path, data):
    from plant.logs.fileio import write_text_atomic

    write_text_atomic(path, json.dumps(data, indent=2, default=float) + "\n")


def main(argv=None):
    """Run the sections; returns the dict written to ``figures.json``."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sections", default=",".join(SECTIONS),
                   help=f"comma-separated subset of {', '.join(SECTIONS)}")
    p.add_argument("--quick", action="store_true", help="small settings (smoke run)")
    p.add_argument("--out", type=Path, default=None,
                   help="directory of figures.json, images/ and figures/ (default: docs, "
                        "or out/figures with --quick)")
    args = p.parse_args(argv)
    sections = [s.strip() for s in args.sections.split(",") if s.strip()]
    unknown = [s for s in sections if s not in SECTIONS]
    if unknown or not sections:
        p.error(f"unknown section(s) {', '.join(unknown)}; choose from {', '.join(SECTIONS)}")
    out = args.out or (REPO / "out" / "figures" if args.quick else REPO / "docs")
    ctx = {"quick": dict(ga_options={"n_gen": 2}, refine_options={"n_starts": 1}) if args.quick else {},
           "images": out / "images", "raw": out / "figures"}
    for d in (out, ctx["images"], ctx["raw"]):
        d.mkdir(parents=True, exist_ok=True)

    path = out / "figures.json"
    data = json.loads(path.read_text()) if path.is_file() else {}
    data["run"] = {"date": datetime.datetime.now().isoformat(timespec="seconds"),
                   "commit": _commit(), "python": platform.python_version(),
                   "machine": platform.platform(), "cpu_count": os.cpu_count(),
                   "numba_num_threads": os.environ.get("NUMBA_NUM_THREADS"),
                   "quick": args.quick, "sections": sections}
    funcs = {name: globals()[name] for name in SECTIONS}
    for name in sections:
        t0 = time.perf_counter()
        print(f"[{name}] ...", flush=True)
        data[name] = funcs[name](ctx)
        data[name + "_section_wall_s"] = time.perf_counter() - t0
        print(f"[{name}] done in {time.perf_counter() - t0:.1f} s", flush=True)
        _write_json_atomic(path, data)  # keep what is done if a later section fails
    print(f"wrote {path} and images in {ctx['images']}")
    return data


def cli(argv=None):
    """Run :func:`main`; a failing run ends with one line on stderr, exit 1."""
    try:
        main(argv)
    except (RuntimeError, ValueError, OSError, subprocess.TimeoutExpired) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(cli())
