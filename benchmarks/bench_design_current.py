"""The robust flexible-joint design's price in current: one pulse of quantisation, in amperes.

``ComputedTorqueController.from_result`` on a flexible result checks the
default design and faster motor loops (:data:`ctc.flexible.ROBUST_DESIGNS`,
up to three times the default bandwidth) over the model-error set and keeps
the one with the smallest worst case in pulses, to a pulse
(:func:`ctc.flexible.select_robust_design`, below).  A faster loop also multiplies
the current the law commands for one pulse of quantisation (``Kp`` grows
with the bandwidth squared, the observer's velocity correction times ``Kv``
with its cube), so a robot tracking at +-1 pulse can see its drive current
flick between the full-scale limits from sample to sample.
``max_current_per_pulse=`` (a fraction of full scale) caps that step for
the faster candidates.

The robust design is the minimax one at the encoder's resolution: of the
candidates whose worst case is within one pulse
(:data:`ctc.flexible.DESIGN_TIE_PULSES`) of the smallest, the one with the
smallest current step (:func:`ctc.flexible.tied_choice`).

This script measures that on cases of the changes benchmark
(``bench_changes.py``; its cache of logs and priors), on the INDEPENDENT
simulator: per case, the CTC that switches to the true payload at the
change (the benchmark's oracle; no payload change: the static CTC) built
by ``from_result`` (the robust design), by ``from_result`` with
``max_current_per_pulse=--cap``, with the default gains
(``robust=None``) and by the strict minimax (``tie 0``: the robust design
with :func:`ctc.flexible.select_robust_design`'s ``tie_pulses=0``, the
rule before the resolution but for equal worst cases, which the current
step decides instead of the order; without ``from_result``'s fallback to
the rigid-equivalent CTC, so a row of a robot no flexible design holds
can differ), as ``--designs`` chooses, each reporting

* the current step for one pulse (A per joint,
  :func:`ctc.protocol.current_per_pulse`),
* max |e| (pulses per joint) from 0.5 s after the (last) change,
* the samples with the commanded current at full scale, per joint,
* the rms of the commanded current's sample-to-sample change (A), per
  joint -- the current's chatter.

Run (about 2 min per case)::

    python benchmarks/bench_design_current.py --seed 20261130 --cases 1,2,8,16
    python benchmarks/bench_design_current.py --seed 20261328 --designs from_result,tie0 \
        --cases 6,16,17,29,31,37,50,55,57,58,66,68 --jobs 2

With ``tie0`` among the designs, cases with a rigid prior are skipped (the
designs compared are the flexible-joint CTC's).  The cases run through
``bench_robustness.run_jobs``: with ``--jobs 2`` on two spawned processes, each
running numba single-threaded (``NUMBA_NUM_THREADS=1`` unless set); a line per
finished case, then the table.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import warnings
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent))

import bench_changes as bc  # noqa: E402
import bench_robustness as br  # noqa: E402
import independent_robot as ir  # noqa: E402


#: The designs ``--designs`` can name, in the order they are printed.
DESIGNS = ("from_result", "cap", "default", "tie0")


def _strict_minimax(prior, log):
    """``from_result``'s robust design by the strict minimax (``tie_pulses=0``), or None for
    a rigid prior."""
    from ctc.contract import IdentifiedModel
    from ctc.flexible import FlexibleJointComputedTorqueController, select_robust_design

    d = IdentifiedModel.from_result(prior)
    if not d.flexible:
        return None
    rig = d.rig(log.rig)
    target = log if rig is log.rig else log.replace(rig=rig)
    first = FlexibleJointComputedTorqueController.from_log(d.f, target, **d.joints())
    return select_robust_design(first, d, target, tie_pulses=0)[0]


def run_case(seed: int, index: int, out: Path, robust_out: Path, cap: float = 0.1,
             designs=("from_result", "cap", "default")) -> list[dict]:
    """The chosen designs' runs on case ``index`` (one dict each; none for a rigid prior
    when ``tie0`` is among them)."""
    import ctc
    import plant
    from ctc.protocol import current_per_pulse

    csv = br.generate(seed, index, robust_out)
    truth = json.loads(csv.with_suffix(".truth.json").read_text())
    s = ir.RobotSettings.from_dict(truth["settings"])
    log = plant.load_log(csv)
    ch = bc.draw_change(seed, index, s)
    prior = bc._prior(csv, robust_out, out, log)
    if "tie0" in designs and prior.get("model", "rigid") == "rigid":
        return []  # a rigid prior: no flexible design to compare
    ts = s.sample_time_s
    after = bc.changed_settings(s, ch)
    changes = [(int(math.ceil(t / ts)), ir.IndependentRobot(c)) for t, c in zip(ch["times_s"], after)]
    k_after = int(math.ceil((ch["times_s"][-1] + 0.5) / ts))
    fs = float(s.current_full_scale_A)
    rows = []
    label = {"from_result": "from_result", "cap": f"cap {cap:g}", "default": "default gains",
             "tie0": "tie 0"}
    options = {"from_result": {}, "cap": dict(max_current_per_pulse=cap),
               "default": dict(robust=None)}
    for key in (k for k in DESIGNS if k in designs):
        design = label[key]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            if key == "tie0":
                inner = _strict_minimax(prior, log)
            else:
                inner = ctc.ComputedTorqueController.from_result(prior, log, **options[key])
            step = current_per_pulse(inner, log)
            run = ir.IndependentRobot(s).run(bc.oracle_of(inner, s, ch, changes), log.trajectory,
                                             log.n_total,
                                             max_step_fraction=ir.max_step_fraction(s),
                                             max_abs_e=bc.DIVERGED_PULSES, changes=changes)
        e = np.abs(run["e"])
        i = np.asarray(run["i_cmd"], dtype=float)
        rows.append(dict(
            index=index, kind=ch["kind"], ppr=list(s.encoder_ppr), design=design,
            controller=type(inner).__name__,
            bandwidth_hz=np.round(inner.gains.bandwidth_hz).astype(int).tolist(),
            current_per_pulse_A=np.round(step, 2).tolist(),
            max_e_after=e[k_after:].max(axis=0).astype(int).tolist() if k_after < len(e) else None,
            saturated=(np.abs(i) >= 0.999 * fs).sum(axis=0).astype(int).tolist(), n=int(len(i)),
            chatter_A=np.round(np.sqrt(np.mean(np.diff(i, axis=0) ** 2, axis=0)), 2).tolist()))
    return rows


def _job(args):
    """One case's rows for :func:`bench_robustness.run_jobs` (its ``stem`` is the case)."""
    seed, index, out, robust_out, cap, designs = args
    return dict(stem=f"case {index:04d}", rows=run_case(seed, index, out, robust_out, cap, designs))


def _print_rows(rows):
    for r in rows:
        if r["controller"] != "FlexibleJointComputedTorqueController":
            r["design"] += " (rigid CTC)"
        print(f"{r['index']:5d} {r['kind']:9} {str(r['ppr']):>11} {r['design']:17} "
              f"{str(r['bandwidth_hz']):>13} {str(r['current_per_pulse_A']):>13} "
              f"{str(r['max_e_after']):>13} "
              f"{str(r['saturated']) + '/' + str(r['n']):>15} {str(r['chatter_A']):>14}",
              flush=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seed", type=int, required=True, help="the changes benchmark's seed")
    ap.add_argument("--cases", type=str, required=True, help="comma-separated case indices")
    ap.add_argument("--out", type=Path, default=bc.DEFAULT_OUT,
                    help="the changes benchmark's cache (its priors)")
    ap.add_argument("--robust-out", type=Path, default=br.DEFAULT_OUT,
                    help="the robustness suite's cache (logs and default identifications)")
    ap.add_argument("--cap", type=float, default=0.1,
                    help="max_current_per_pulse of the capped design (fraction of full scale)")
    ap.add_argument("--designs", type=str, default="from_result,cap,default",
                    help=f"comma-separated designs to run, of {', '.join(DESIGNS)} "
                         "(tie0: the strict minimax)")
    ap.add_argument("--jobs", type=int, default=1, help="cases run at once (processes)")
    a = ap.parse_args(argv)
    if not a.cap > 0:
        ap.error("--cap must be > 0")
    if a.jobs < 1:
        ap.error("--jobs must be >= 1")
    try:
        cases = [int(c) for c in a.cases.split(",")]
    except ValueError:
        ap.error(f"--cases must be comma-separated integers, got {a.cases!r}")
    designs = tuple(d.strip() for d in a.designs.split(",") if d.strip())
    if not designs or not set(designs) <= set(DESIGNS):
        ap.error(f"--designs must name some of {', '.join(DESIGNS)}, got {a.designs!r}")
    jobs = [(a.seed, index, a.out, a.robust_out, a.cap, designs) for index in cases]
    done = br.run_jobs(_job, jobs, a.jobs)  # a line per finished case, then the table
    print(f"{'case':>5} {'change':9} {'ppr':>11} {'design':17} {'bandwidth Hz':>13} "
          f"{'A per pulse':>13} {'max|e| after':>13} {'at full scale':>15} {'chatter A rms':>14}")
    for res in done:
        _print_rows(res["rows"])
    return 0


if __name__ == "__main__":
    sys.exit(main())
