"""A gearbox stiffness loss on every flexible robot of a changes draw, on the INDEPENDENT simulator.

:mod:`bench_changes` draws one change per robot, so a draw holds only a few
stiffness changes (three in 56 cases of seed 20261327).  This benchmark
gives every two-mass flexible robot of the same draw (the same logs, the
same default identifications as priors) a joint stiffness change x
``--factor`` (default 0.7, the issue's) at a random time, drawn per robot
from ``numpy.random.default_rng([change_seed, index])`` uniform in
0.6-2.5 s (at most 1 s before the log's end; a robot whose log leaves less
than 0.3 s before that is skipped, and counted), and runs the static CTC
(``ctc.ComputedTorqueController.from_result``) and the adaptive CTC
(``ctc.AdaptiveComputedTorqueController.from_log``, default window and fixed
latency) through it on :mod:`independent_robot`.  The robot carries no new
payload, so every payload update of the adaptive CTC is a false one.

Scores per robot (max abs(e) in pulses per joint, "after" from 0.5 s after
the change to the end): a false payload update (any update to more than
0.05 kg), and one before the supervisor named the change (an update's time
is when it took effect, after the identification's latency; an event's,
the end of the window that raised it); the change
named (an ``'unexplained'`` event with ``cause='drive'``) and reported (any
``'unexplained'`` event); the adaptive CTC no worse than the static one + 1
pulse after the change; no divergence.

Run
---
::

    pip install -e ".[bench]"
    python benchmarks/bench_stiffness_changes.py --seed 20261327 --change-seed 20261379 --jobs 2

``--out`` is the changes benchmark's output folder, whose ``priors`` it
reuses (the robustness suite's cached identifications first); a prior
missing from both is identified anew and cached there.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import traceback
import warnings
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent))

import bench_changes as bc  # noqa: E402
import bench_robustness as br  # noqa: E402
import independent_robot as ir  # noqa: E402

#: An update to more than this mass is a payload (the changes benchmark's false-update line).
FALSE_MASS_KG = 0.05

#: A change earlier than this leaves too little of the run before it (the calibration windows).
EARLIEST_S = 0.3


def change_time(change_seed: int, index: int, duration_s: float) -> float:
    """The change's time (s): uniform in 0.6-2.5 s per robot, at most 1 s before the end."""
    t = float(np.random.default_rng([change_seed, index]).uniform(0.6, 2.5))
    return min(t, duration_s - 1.0)


def run_robot(seed: int, index: int, change_seed: int, factor: float, out: Path,
              robust_out: Path) -> dict | None:
    """Static and adaptive CTC through a stiffness change on one robot; None when rigid."""
    import ctc
    import plant

    csv = br.generate(seed, index, robust_out)
    truth = json.loads(csv.with_suffix(".truth.json").read_text())
    s = ir.RobotSettings.from_dict(truth["settings"])
    if not s.flexible:
        return None
    log = plant.load_log(csv)
    ts, n = s.sample_time_s, log.n_total
    t = change_time(change_seed, index, n * ts)
    if t < EARLIEST_S:
        raise RuntimeError(f"no feasible change time: the log is {n * ts:.2f} s long")
    ch = dict(kind="stiffness", factor=float(factor), times_s=[t])
    changes = [(int(math.ceil(t / ts)), ir.IndependentRobot(c))
               for c in bc.changed_settings(s, ch)]
    k0, k_after = changes[0][0], int(math.ceil((t + 0.5) / ts))
    prior = bc._prior(csv, robust_out, out, log)
    row = dict(stem=csv.stem, index=index, ppr=list(s.encoder_ppr), t_s=t, factor=float(factor))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for name in ("static", "adaptive"):
            c = (ctc.ComputedTorqueController.from_result(prior, log) if name == "static"
                 else ctc.AdaptiveComputedTorqueController.from_log(prior, log))
            run = ir.IndependentRobot(s).run(c, log.trajectory, n,
                                             max_step_fraction=ir.max_step_fraction(s),
                                             max_abs_e=bc.DIVERGED_PULSES, changes=changes)
            e = np.abs(run["e"])
            row[name] = dict(success=bool(run["success"]),
                             max_e_before=e[:k0].max(axis=0).astype(int).tolist(),
                             max_e_after=e[k_after:].max(axis=0).astype(int).tolist())
            if name == "adaptive":
                row["updates"] = [[float(a), float(b)] for a, b in c.payload_history]
                row["events"] = [dict(t_s=float(ev["t_s"]), kind=ev["kind"], cause=ev.get("cause"))
                                 for ev in c.events]
    return row


def score(row: dict) -> dict:
    """The robot's verdicts (see the module's docstring)."""
    named = [ev["t_s"] for ev in row["events"] if ev["kind"] == "unexplained"
             and ev["cause"] == "drive"]
    t_named = min(named) if named else math.inf
    false = [(t, m) for t, m in row["updates"] if m > FALSE_MASS_KG]
    st, ad = row["static"], row["adaptive"]
    return dict(
        no_false_update=not false,
        no_false_update_before_named=not any(t < t_named for t, _ in false),
        named=bool(named),
        reported=any(ev["kind"] == "unexplained" for ev in row["events"]),
        not_worse=bool(ad["success"] and all(a <= b + 1 for a, b in
                                             zip(ad["max_e_after"], st["max_e_after"]))),
        no_divergence=bool(ad["success"]))


def _job(args):
    seed, index, change_seed, factor, out, robust_out = args
    stem = br.stem_of(seed, index)
    try:
        row = run_robot(seed, index, change_seed, factor, Path(out), Path(robust_out))
    except Exception as exc:  # noqa: BLE001
        if isinstance(exc, RuntimeError) and ("no stable drive" in str(exc)
                                              or "no feasible" in str(exc)):
            return dict(stem=stem, skipped=str(exc))
        return dict(stem=stem, error=f"{type(exc).__name__}: {exc}",
                    trace=traceback.format_exc()[-2000:])
    return dict(stem=stem, skipped="rigid") if row is None else row


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=58, help="robots drawn (the changes draw's --n)")
    ap.add_argument("--seed", type=int, default=20261327, help="the changes draw's seed")
    ap.add_argument("--change-seed", type=int, default=20261379,
                    help="the seed of the change times")
    ap.add_argument("--factor", type=float, default=0.7, help="the stiffness factor")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--out", type=Path, default=bc.DEFAULT_OUT,
                    help="the changes benchmark's --out (its cached priors)")
    ap.add_argument("--robust-out", type=Path, default=br.DEFAULT_OUT,
                    help="the robustness suite's cache (logs and default identifications)")
    a = ap.parse_args(argv)
    if a.n < 1 or a.jobs < 1 or not a.factor > 0 or a.seed < 0 or a.change_seed < 0:
        ap.error("--n and --jobs must be >= 1, --factor > 0 and the seeds >= 0")
    jobs = [(a.seed, i, a.change_seed, a.factor, str(a.out), str(a.robust_out))
            for i in range(a.n)]
    rows = br.run_jobs(_job, jobs, a.jobs)
    skipped = [r for r in rows if "skipped" in r]
    n_rigid = sum(r["skipped"] == "rigid" for r in skipped)
    rows = [r for r in rows if "skipped" not in r]
    errors = [r for r in rows if "error" in r]
    rows = [r for r in rows if "error" not in r]
    print(f"\nstiffness x{a.factor:g} on every flexible robot of draw {a.seed} "
          f"(change times from seed {a.change_seed}); max abs(e) pulses, after = from 0.5 s "
          f"after the change\n")
    print(f"{'case':5} {'ppr':13} {'t (s)':>6}  {'static after':13} {'adaptive after':15} "
          f"{'updates (t s, kg)':34} events")
    for r in rows:
        r["verdict"] = score(r)
        ups = ", ".join(f"{t:.2f}:{m:.2f}" for t, m in r["updates"]) or "-"
        evs = ", ".join(f"{ev['kind']}:{ev['cause']}@{ev['t_s']:.2f}" if ev["cause"]
                        else f"{ev['kind']}@{ev['t_s']:.2f}" for ev in r["events"]) or "-"
        print(f"{r['stem'][-4:]:5} {str(r['ppr']):13} {r['t_s']:6.2f}  "
              f"{str(r['static']['max_e_after']):13} {str(r['adaptive']['max_e_after']):15} "
              f"{ups:34} {evs}")
    n = len(rows)
    print(f"\nsummary over {n} flexible robots ({len(errors)} errors; {n_rigid} rigid robots "
          f"and {len(skipped) - n_rigid} draws without a stable P loop, a feasible reference "
          f"or a change time skipped):")
    for key, text in [("no_false_update", "no false payload update (> 0.05 kg) at all"),
                      ("no_false_update_before_named", "no false payload update before the "
                                                       "change was named"),
                      ("named", "the change named (cause 'drive')"),
                      ("reported", "the change reported ('unexplained')"),
                      ("not_worse", "adaptive <= static + 1 pulse after the change"),
                      ("no_divergence", "adaptive does not diverge")]:
        k = sum(r["verdict"][key] for r in rows)
        print(f"  {text:58} {k:3d}/{n}")
    worst = sorted(rows, key=lambda r: (r["verdict"]["no_false_update_before_named"],
                                        r["verdict"]["not_worse"], r["verdict"]["named"],
                                        -max(a - b for a, b in zip(r["adaptive"]["max_e_after"],
                                                                   r["static"]["max_e_after"]))))
    print("\nworst five:")
    for r in worst[:5]:
        print(f"  {r['stem']} ppr {r['ppr']} stiffness x{r['factor']:g} @ {r['t_s']:.2f} s: "
              f"static {r['static']['max_e_after']}, adaptive {r['adaptive']['max_e_after']}; "
              f"updates {[(round(t, 2), round(m, 2)) for t, m in r['updates']]}; failed: "
              + (", ".join(k for k, v in r["verdict"].items() if not v) or "none"))
    for r in errors:
        print(f"  ERROR {r['stem']}: {r['error']}")
    return 1 if errors else 0


if __name__ == "__main__":
    sys.exit(main())
