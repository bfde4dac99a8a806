"""The methods side by side: GA (paper), GA + refinement, DE, CMA-ES, IDIM-LS, IDIM-IV.

What it measures
----------------
On the development logs and on generated logs (:func:`plant.emulate_log`,
paper trajectory T = 3 s, encoders 250 / 1000 / 4096 ppr with the loop gain
kept in A/rad, the paper log's f perturbed +-5 % per log, rigid and the
"stiff" flexible plant of ``bench_coverage``), each method identifies f:

``paper`` ``identify(method='paper')``; ``ga+pem`` ``identify()`` (default);
``de`` / ``cmaes`` scipy's differential evolution / CMA-ES on the output
error of eq. 4 (``bench_optimisers``'s settings, the paper's 3120
simulations); ``idim-ls`` / ``idim-iv`` the inverse dynamic model
(:mod:`identification.idim`).

Per log and method: error per f (% of the truth), the validation output
error (eq. 4 at 2 substeps on a second log of the same rig with another
trajectory, relative to the true f's; 1.00 = as good as the truth) and the
wall time.  ``--quick`` runs the development logs only.

Usage (from the repository root)::

    PYTHONPATH=. python benchmarks/bench_methods.py [--quick] [--methods ...] [--out F.json]
        [--rst TABLE.rst]
"""
from __future__ import annotations

import argparse
import dataclasses
import importlib.util
import json
import math
import time
import warnings
from pathlib import Path

import numpy as np

import identification
import plant
from identification import OutputError

HERE = Path(__file__).resolve().parent
DATA = HERE.parent / "tests" / "data"
METHODS = ("paper", "ga+pem", "de", "cmaes", "idim-ls", "idim-iv")


def _optimisers():
    spec = importlib.util.spec_from_file_location("bench_optimisers", HERE / "bench_optimisers.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _validation_trajectory():
    return plant.Trajectory.from_terms(
        [-0.4, 0.6], [[(0.35, 2 * math.pi / 3.0, 0.0), (0.15, 2 * math.pi / 1.0, 0.7)],
                      [(0.45, 2 * math.pi / 1.5, 1.2), (0.12, 2 * math.pi / 0.6, 0.3)]], 0.6)


def logs(quick):
    """Name -> (identification log, validation log, true f)."""
    out = {}
    for stem, val in (("puma560_paper_rigid", "puma560_validation_rigid"),
                      ("puma560_validation_rigid", "puma560_paper_rigid"),
                      ("puma560_paper_drill_flex", None)):
        log = plant.load_log(DATA / f"{stem}.csv")
        f = np.array(json.loads((DATA / f"{stem}.truth.json").read_text())["f_vector"])
        vlog = plant.load_log(DATA / f"{val}.csv") if val else plant.emulate_log(
            log, f, trajectory=_validation_trajectory(), duration_s=3.0, name="val")
        out[stem] = (log, vlog, f)
    if quick:
        return out
    base = out["puma560_paper_rigid"][0]
    f0 = out["puma560_paper_rigid"][2]
    seed = 0
    for flex in (None, "stiff"):
        for ppr in (250, 1000, 4096):
            rng = np.random.default_rng(500 + seed)
            seed += 1
            f = f0 * (1 + 0.05 * rng.uniform(-1, 1, 9))
            f[2:4] = base.rig.a3_m * f[4:6]
            scale = np.array(base.rig.encoder_ppr, float) / ppr
            rig = dataclasses.replace(base.rig, encoder_ppr=(ppr, ppr), p_gain_A_per_pulse=tuple(
                float(v) for v in np.array(base.rig.p_gain_A_per_pulse) * scale))
            fl = None if flex is None else plant.FlexibleJoints((60000.0, 15000.0), (6.0, 1.0),
                                                                200e-6)
            name = f"{'rigid' if flex is None else 'flex'}_{ppr}"
            log = plant.emulate_log(base, f, rig=rig, trajectory=plant.Trajectory.paper(3.0),
                                    duration_s=3.0, flexible=fl, name=name)
            vlog = plant.emulate_log(base, f, rig=rig, trajectory=_validation_trajectory(),
                                     duration_s=3.0, flexible=fl, name=name + "_val")
            out[name] = (log, vlog, f)
    return out


def run(method, log, seed, opt):
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if method in ("paper", "ga+pem", "idim-ls", "idim-iv"):
            f = identification.identify(log, method=method, rng=seed, progress=False).f
        elif method == "de":
            f = opt.run_de(log, log.rig.bounds, seed, None)["f"]
        else:
            f = opt.run_cmaes(log, log.rig.bounds, seed, None)["f"]
    return np.asarray(f), time.perf_counter() - t0


WELL = (0, 1, 3, 5, 6, 8)  # f1 f2 f4 f6 f7 f9: well excited by the paper trajectory


def rst_table(rows):
    """The docs' list-table of the comparison (``docs/figures/methods_table.rst``).

    Each cell: max abs(error) (%) over the well-excited f / over all nine f;
    validation output error relative to the true f's; wall time (s).
    """
    logs_ = list(dict.fromkeys(r["log"] for r in rows))
    methods = list(dict.fromkeys(r["method"] for r in rows))
    cell = {(r["log"], r["method"]): r for r in rows}
    out = [".. list-table:: Methods side by side (bench_methods.py, seed 0)",
           "   :header-rows: 1", "", "   * - log"]
    out += [f"     - {m}" for m in methods]
    for lg in logs_:
        out.append(f"   * - {lg.replace('puma560_', '')}")
        for m in methods:
            r = cell.get((lg, m))
            if r is None:
                out.append("     -")
                continue
            e = np.abs(np.asarray(r["error_pct"]))
            v = r["validation_ratio"]
            vs = f"{v:.2f}" if v < 1e3 else f"{v:.0e}"
            out.append(f"     - {e[list(WELL)].max():.1f} / {e.max():.0f}; {vs}; "
                       f"{r['wall_time_s']:.1f}")
    return "\n".join(out) + "\n"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="development logs only")
    ap.add_argument("--methods", nargs="+", default=list(METHODS), choices=METHODS)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", help="write the figures as JSON")
    ap.add_argument("--rst", help="write the docs' list-table (reStructuredText) to this file")
    args = ap.parse_args(argv)
    opt = _optimisers()
    plant.warm_up(closed_loop=True)
    rows = []
    head = "".join(f"{'f' + str(i + 1):>7}" for i in range(9))
    print(f"{'log':<26}{'method':<9}{head}  val/true  time s")
    for name, (log, vlog, f) in logs(args.quick).items():
        val = OutputError(vlog, substeps=2)
        v_true = float(val(f[None])[0])
        for m in args.methods:
            fh, dt = run(m, log, args.seed, opt)
            err = 100 * (fh - f) / np.abs(f)
            v = float(val(fh[None])[0]) / v_true
            print(f"{name:<26}{m:<9}{''.join(f'{e:7.1f}' for e in err)}  {v:8.2f}  {dt:6.1f}",
                  flush=True)
            rows.append(dict(log=name, method=m, error_pct=err.tolist(), validation_ratio=v,
                             wall_time_s=dt))
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(json.dumps(rows, indent=1))
    if args.rst:
        Path(args.rst).parent.mkdir(parents=True, exist_ok=True)
        Path(args.rst).write_text(rst_table(rows))


if __name__ == "__main__":
    main()
