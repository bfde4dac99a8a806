"""Before/after: this tree against an earlier commit, side by side in one run.

Checks the baseline commit out into a temporary git worktree, then runs the
same measurements alternately in fresh processes of both trees (each with
its own numba cache, so neither loads the other's kernels), and prints, per
tree:

* the first call in a fresh process with an empty numba cache: imports and
  ``identify(method="paper")`` on the paper log, compilation included;
* the paper's GA budget on the paper log, ``identify(method="paper")``
  (3120 simulations), and the default method, wall time excluding
  compilation, best and median over all runs;
* whether both trees identify the same f (max relative difference).

The machine's speed drifts from minute to minute; alternating the trees
spreads the drift over both.  Usage::

    python benchmarks/bench_versus.py --baseline 4464c6b [--rounds 4] [--runs 5]

Needs git and a clone of the repository (the baseline is read from its
history); the worktree is removed afterwards.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "tests" / "data"

_SNIPPET = r"""
import json, sys, time
sys.path.insert(0, {tree!r})
t0 = time.perf_counter()
import plant, identification
log = plant.load_log({log!r})
identification.identify(log, method="paper", rng=0, progress=False)
out = {{"first_call_s": time.perf_counter() - t0}}
for method in ("paper", "ga+pem"):
    identification.identify(log, method=method, rng=0, progress=False)  # warm
    walls = []
    for _ in range({runs}):
        r = identification.identify(log, method=method, rng=0, progress=False)
        walls.append(r.wall_time_s)
    out[method] = {{"walls": walls, "f": [float(v) for v in r.f]}}
print(json.dumps(out))
"""


def _run_tree(tree, cache, runs):
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache))
    code = _SNIPPET.format(tree=str(tree), log=str(DATA / "puma560_paper_rigid.csv"), runs=runs)
    r = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                       check=True, cwd=tempfile.gettempdir())
    return json.loads(r.stdout.strip().splitlines()[-1])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--baseline", required=True, help="git revision to compare with")
    ap.add_argument("--rounds", type=int, default=4, help="alternations of the two trees")
    ap.add_argument("--runs", type=int, default=5, help="identifications per method and round")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        base = Path(tmp) / "baseline"
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(base),
                        args.baseline], check=True, capture_output=True)
        try:
            trees = {"baseline " + args.baseline: base, "this tree": ROOT}
            res = {k: [] for k in trees}
            for rnd in range(args.rounds):
                for label, tree in trees.items():
                    cache = Path(tmp) / f"cache-{label.split()[0]}-{rnd}"  # empty: first compile
                    res[label].append(_run_tree(tree, cache, args.runs))
        finally:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(base)],
                           capture_output=True)
    print(f"paper log, {args.rounds} alternating rounds x {args.runs} runs per method "
          "(wall time excludes compilation)")
    print(f"{'tree':>24} {'first call (median)':>20} {'paper GA best / median':>24} "
          f"{'default best / median':>23}")
    med = {}
    for label, rounds in res.items():
        comp = np.median([r["first_call_s"] for r in rounds])
        cols = []
        for method in ("paper", "ga+pem"):
            w = np.array([v for r in rounds for v in r[method]["walls"]])
            med[label, method] = np.median(w)
            cols.append(f"{w.min():.3f} / {np.median(w):.3f} s")
        print(f"{label:>24} {comp:>18.1f} s {cols[0]:>24} {cols[1]:>23}")
    (b, _), (t, _) = list(res.items())
    for method in ("paper", "ga+pem"):
        fb = np.array(res[b][0][method]["f"])
        ft = np.array(res[t][0][method]["f"])
        print(f"{method}: this tree / baseline (medians) {med[t, method] / med[b, method]:.2f}; "
              f"identified f max relative difference {np.max(np.abs(ft - fb) / np.abs(fb)):.1e}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
