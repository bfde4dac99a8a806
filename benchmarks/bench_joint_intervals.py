"""Do the ranges of the joint parameters cover the truth where the standard errors do not?

Every compliant robot among the robustness suite's draws of a seed
(:func:`bench_robustness.generate`: Robotics Toolbox dynamics, the suite's own
two-mass joints, backlash and drive, DOP853 -- no code shared with the
library's plant) is identified with the library's default call
(``identification.identify(log, rng=0)``, cached in ``--out``).  For each
flexible result and each joint's stiffness K, damping D and reflected motor
inertia ``Jm k^2``, the truth is compared with

* the **range** of ``result['joint_intervals']``
  (:func:`identification.flexible.joint_intervals`: the values that predict
  the log within the model choice's floor allowance, one parameter at a time),
  read at the scan's resolution (its first factor, x1.25, either side: an end
  equal to the fit means "within x1.25");
* the **2 sigma interval** of the Gauss-Newton standard errors (``x_std`` of
  ``log10 K``, ``D`` and the inertia share ``r``), widened by the same x1.25
  either side (a fair comparison: a fit within 2 % of the truth is covered
  by both).

Reported: per log the fit's ratio to the truth, which parameters the
result calls undetermined and how many robots beside the fit its log
allows (``corners``, the flexible-joint CTC's extra scenarios); then, over the fits the model choice calls
adequate and at the floor (held-back cost <= 1.1 floors), how many truths
each interval covers, and how many flags are right (an undetermined
parameter whose fit is more than x1.25 off the truth, or a determined one
within it).

Run
---
::

    pip install -e ".[bench]"
    python benchmarks/bench_joint_intervals.py --n 58 --seed 20261327 --jobs 2 \\
        --txt docs/figures/joint_intervals_20261327.txt
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import warnings
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import bench_robustness as br  # noqa: E402

DEFAULT_OUT = HERE / "out" / "joint_intervals"
#: The scan's resolution: an end equal to the fit means "within the first factor".
RESOLUTION = 1.25
QUANTITIES = ("K", "D", "Jm k^2")


def _result(seed, index, out, robust_out):
    """(stem, result dict or None, truth) of draw ``index``; None for a rigid robot."""
    import identification
    import plant

    csv = br.generate(seed, index, robust_out)
    truth = json.loads(csv.with_suffix(".truth.json").read_text())
    stem = csv.stem
    if truth["joints"]["model"] != "flexible":
        return stem, None, truth
    path = out / "results" / f"{stem}.result.json"
    if not path.exists():
        log = plant.load_log(csv)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = identification.identify(log, rng=0, progress=False)
        path.parent.mkdir(parents=True, exist_ok=True)
        res.save_json(path)
    return stem, json.loads(path.read_text()), truth


def _job(args):
    seed, index, out, robust_out = args
    try:
        return _result(seed, index, Path(out), Path(robust_out))
    except RuntimeError as exc:  # a draw without a stable drive or a feasible reference
        return f"{seed}_{index}", None, {"skipped": str(exc)}


def sigma_interval(res, p):
    """The 2-sigma interval of joint parameter p (0..5: K2 K3 D2 D3 Jm2k2^2 Jm3k3^2)."""
    names, x, sd = res["x_names"], np.asarray(res["x"], float), res.get("x_std")
    col = ("log10_K2", "log10_K3", "D2", "D3", "r2", "r3")[p]
    i = names.index(col)
    s = float(sd[i]) if sd is not None and sd[i] is not None else math.inf
    if p < 2:
        return 10 ** (x[i] - 2 * s), 10 ** (x[i] + 2 * s)
    if p < 4:
        return x[i] - 2 * s, x[i] + 2 * s
    f = x[6] if p == 4 else x[0]  # Jm k^2 = r f7 (joint 2), r f1 (joint 3)
    return (x[i] - 2 * s) * f, (x[i] + 2 * s) * f


def analyse(rows):
    """Per log lines and the summary counts."""
    lines, cover = [], {q: dict(n=0, range=0, sigma=0, right=0, flagged=0, off=0)
                        for q in QUANTITIES}
    for stem, res, truth in rows:
        if res is None:
            continue
        j = truth["joints"]
        tv = np.array(j["stiffness_Nm_per_rad"] + j["damping_Nms_per_rad"]
                      + j["motor_inertia_reflected_kgm2"])
        ji = res.get("joint_intervals")
        mc = res.get("model_choice") or {}
        floors = mc.get("floor_ratio")
        at_floor = (res.get("model") == "flexible" and ji is not None and mc.get("adequate")
                    and floors is not None and floors <= 1.1)
        n_corners = len((ji or {}).get("corners") or ())
        if res.get("model") != "flexible" or ji is None:
            lines.append(f"{stem}  model {res.get('model')}: no joint ranges")
            continue
        cells = []
        for p in range(6):
            v, lo, hi = ji["value"][p], ji["low"][p], ji["high"][p]
            lo_r, hi_r = lo / RESOLUTION, hi * RESOLUTION
            in_range = lo_r <= tv[p] <= hi_r
            s_lo, s_hi = sigma_interval(res, p)
            in_sigma = s_lo / RESOLUTION <= tv[p] <= s_hi * RESOLUTION  # the same slack
            flagged = ji["names"][p] in ji["undetermined"]
            off = not (1 / RESOLUTION <= v / tv[p] <= RESOLUTION) if tv[p] > 0 else False
            cells.append(f"{ji['names'][p].split('_')[0]} {v / tv[p]:.3g}"
                         f"{'*' if flagged else ''}{'' if in_range else ' R'}"
                         f"{'' if in_sigma else ' S'}")
            if at_floor:
                c = cover[QUANTITIES[p // 2]]
                c["n"] += 1
                c["range"] += in_range
                c["sigma"] += in_sigma
                c["flagged"] += flagged
                c["off"] += off
                c["right"] += flagged == off
        lines.append(f"{stem}  {floors:6.3g} floors{'' if at_floor else ' (not at the floor)'}  "
                     + "  ".join(cells) + (f"  corners {n_corners}" if n_corners else "")
                     + ("" if ji.get("judged", True) else "  (ranges not judged)"))
    return lines, cover


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=58)
    ap.add_argument("--seed", type=int, default=20261327)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT)
    ap.add_argument("--robust-out", type=Path, default=br.DEFAULT_OUT,
                    help="the robustness suite's output (its cached logs)")
    ap.add_argument("--txt", type=Path, default=None, help="also write the report here")
    a = ap.parse_args(argv)
    if a.n < 1 or a.jobs < 1:
        ap.error("--n and --jobs must be >= 1")
    args = [(a.seed, i, str(a.out), str(a.robust_out)) for i in range(a.n)]
    if a.jobs == 1:
        rows = [_job(x) for x in args]
    else:
        with ProcessPoolExecutor(a.jobs) as ex:
            rows = list(ex.map(_job, args))
    lines, cover = analyse(rows)
    n_flex = sum(1 for _, r, _ in rows if r is not None)
    out = [f"joint ranges vs 2-sigma standard errors, seed {a.seed}, {a.n} draws, "
           f"{n_flex} compliant robots (identify(log, rng=0))",
           "per log: fit / truth per parameter; * the result calls it undetermined; "
           "R the truth outside the range, S outside 2 sigma (both widened x1.25 either side)", ""]
    out += lines
    out += ["", "over the flexible fits at the floor (adequate, <= 1.1 held-back floors):"]
    for q, c in cover.items():
        n = max(c["n"], 1)
        out.append(f"  {q:<7} {c['n']:3d} values: truth in the range {c['range']:3d} "
                   f"({100 * c['range'] / n:5.1f} %), in 2 sigma {c['sigma']:3d} "
                   f"({100 * c['sigma'] / n:5.1f} %); flagged {c['flagged']}, fit > x1.25 off "
                   f"{c['off']}, flag right {c['right']}/{c['n']}")
    text = "\n".join(out)
    print(text)
    if a.txt is not None:
        tmp = a.txt.with_suffix(a.txt.suffix + ".tmp")
        tmp.write_text(text + "\n")
        tmp.replace(a.txt)


if __name__ == "__main__":
    main()
