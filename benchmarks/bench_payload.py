"""Real rigs (issue 7): flexible / noisy / coarse logs and on-line payload identification.

Prints, in sections (``--sections``, default all):

``spectrum``
    :func:`identification.diagnostics.error_spectrum` of the development
    logs: the detected flexible mode, the lowest closed-loop resonance and the
    suggested low-pass cut-off (figures ``spectrum_<stem>.png``).
``drill``
    Full identification of ``puma560_paper_drill_flex`` (default method,
    seed 0) unfiltered, with the suggested cut-off and with other cut-offs:
    relative errors of f1..f9 against the rigid-equivalent truth, wall time.
    Acceptance: the well-excited f1 f2 f4 f6 f7 f9 within 5 %.
``coarse``
    A coarse-encoder, other-gain log (250 ppr, P = 0.3 A/pulse): the paper
    log re-simulated with that rig (substeps 48, true rigid f), saved with
    ``log.save``, loaded back from its sidecar alone and identified.
``payload``
    On-line payload identification (``identify(..., payload=True)``) with a
    prior identified on ``puma560_paper_rigid`` (and, for comparison, the
    true unloaded f): windows of ``puma560_paper_drill_flex`` of 0.2, 0.4
    and 0.8 s at several start times, unfiltered and with the suggested
    cut-off; the same windows of a synthetic *rigid* loaded log (the paper
    log re-simulated with the drill's true f).  Identified mass (true
    1.5 kg) and ``wall_time_s`` (kernels compiled).

Only benchmarks, tests and examples read the ``*.truth.json`` files.  The
development logs are looked up in ``PUMA_DATA_DIR`` or ``tests/data``.
Run from the repository root (long: start it in the background)::

    NUMBA_NUM_THREADS=2 nohup python benchmarks/bench_payload.py > out/bench_payload.txt &
    python benchmarks/bench_payload.py --sections spectrum,payload

Figures and logs go to ``out/bench_payload/`` (``--out``).
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import identification  # noqa: E402
import plant  # noqa: E402
from identification.diagnostics import error_spectrum  # noqa: E402

PAPER = "puma560_paper_rigid"
VALID = "puma560_validation_rigid"
DRILL = "puma560_paper_drill_flex"
WELL_EXCITED = (0, 1, 3, 5, 6, 8)  # f1 f2 f4 f6 f7 f9
DRILL_MASS_KG = 1.5
SECTIONS = ("spectrum", "drill", "coarse", "payload")


def data_dir():
    """Directory of the development logs (``PUMA_DATA_DIR`` or ``tests/data``)."""
    env = os.environ.get("PUMA_DATA_DIR")
    return Path(env) if env else Path(__file__).resolve().parents[1] / "tests" / "data"


def load(stem):
    """The development log ``stem``."""
    return plant.load_log(data_dir() / f"{stem}.csv")


def truth_f(stem):
    """True f1..f9 of a development log (benchmarks may read the truth files)."""
    return np.array(json.loads((data_dir() / f"{stem}.truth.json").read_text())["f_vector"])


def rel_err_pct(f, f_true):
    """Relative errors (%) of f against the truth."""
    return 100.0 * (np.asarray(f) - f_true) / np.abs(f_true)


def fmt_errs(err):
    """f1..f9 errors, well-excited ones marked with * when above 5 %."""
    return " ".join(f"{e:+7.2f}{'*' if (i in WELL_EXCITED and abs(e) > 5) else ' '}"
                    for i, e in enumerate(err))


def header():
    """Column heads matching :func:`fmt_errs`."""
    return " ".join(f"{'f' + str(i + 1):>8s}" for i in range(9))


# --------------------------------------------------------------------- sections
def section_spectrum(out):
    """Error spectra of the development logs; returns the drill log's cut-off."""
    print("\n== error spectrum (Welch, default segment) ==")
    cut = None
    for stem in (PAPER, VALID, DRILL):
        spec = error_spectrum(load(stem))
        print(f"  {spec.summary()}  [nperseg {spec.nperseg}, {spec.n_segments} segments]")
        spec.plot().savefig(out / f"spectrum_{stem}.png", dpi=110)
        if stem == DRILL:
            cut = spec.cutoff_hz
    return cut


def section_drill(cutoffs):
    """Full identification of the drill/flex log at several cut-offs."""
    log, ft = load(DRILL), truth_f(DRILL)
    print(f"\n== {DRILL}: full identification (default method, seed 0) ==")
    print("  relative error of f (%) vs the rigid-equivalent truth; * = well-excited and > 5 %")
    print(f"  {'lowpass':>12s} {header()}   wall_s  pass")
    rows = []
    for label, lp in cutoffs:
        res = identification.identify(log, rng=0, lowpass_hz=lp, progress=False)
        err = rel_err_pct(res.f, ft)
        ok = bool(np.all(np.abs(err[list(WELL_EXCITED)]) <= 5.0))
        print(f"  {label:>12s} {fmt_errs(err)} {res.wall_time_s:7.1f}  {ok}", flush=True)
        rows.append((label, lp, err, res.wall_time_s, ok))
    return rows


def make_coarse_log(path):
    """Paper log re-simulated on a 250 ppr / P = 0.3 A/pulse rig; saved to ``path``."""
    base = load(PAPER)
    rig = dataclasses.replace(base.rig, encoder_ppr=(250, 250), p_gain_A_per_pulse=(0.3, 0.3))
    log = base.replace(rig=rig)
    e = plant.simulate_experiment(log, truth_f(PAPER), substeps=48)
    i = e * np.asarray(rig.p_gain_A_per_pulse)[None, :]
    log = log.replace(e_pulses=e, i_A=i)
    log.save(path)
    return log


def section_coarse(out):
    """Coarse-encoder / other-gain log: save, load from the sidecar alone, identify."""
    print("\n== coarse encoder / other gain (250 ppr, P = 0.3 A/pulse), rigid, true f ==")
    made = make_coarse_log(out / "puma560_paper_rigid_ppr250_p03")
    log = plant.load_log(out / "puma560_paper_rigid_ppr250_p03.csv")
    # (the in-memory copy's sidecar dict is not synced by replace(); the file's is)
    assert log.rig == made.rig and np.array_equal(log.e_pulses, made.e_pulses)
    assert log.sidecar["encoder_ppr"] == [250, 250]
    print(f"  saved and re-loaded {log.name}: ppr {log.rig.encoder_ppr}, "
          f"P {log.rig.p_gain_A_per_pulse} A/pulse, max |e| {np.abs(log.e_pulses).max(0)} pulses")
    spec = error_spectrum(log)
    print(f"  spectrum: {spec.summary()}")
    res = identification.identify(log, rng=0, lowpass_hz=spec.cutoff_hz, progress=False)
    err = rel_err_pct(res.f, truth_f(PAPER))
    print(f"  {'':>12s} {header()}   wall_s")
    print(f"  {'identified':>12s} {fmt_errs(err)} {res.wall_time_s:7.1f}", flush=True)
    return err


def synthetic_loaded_log():
    """The paper log re-simulated (rigid, substeps 48) with the drill's true f."""
    base = load(PAPER)
    e = plant.simulate_experiment(base, truth_f(DRILL), substeps=48)
    i = e * np.asarray(base.rig.p_gain_A_per_pulse)[None, :]
    return base.replace(e_pulses=e, i_A=i)


def payload_run(log, prior, lowpass_hz, method="ga+pem"):
    """One payload identification: (mass kg, wall s)."""
    res = identification.identify(log, payload=True, prior=prior, lowpass_hz=lowpass_hz,
                                  rng=0, progress=False, method=method)
    return res.to_dict()["payload_mass_kg"], res.wall_time_s


def section_payload(cutoff, starts, lengths):
    """Payload identification on windows of the drill/flex and a synthetic rigid loaded log."""
    paper = load(PAPER)
    print("\n== payload identification (payload=True, default method) ==")
    t = time.perf_counter()
    prior = identification.identify(paper, rng=0, progress=False)
    err = rel_err_pct(prior.f, truth_f(PAPER))
    print(f"  prior: identify({PAPER}, rng=0) in {time.perf_counter() - t:.1f} s; "
          f"f errors (%): {fmt_errs(err)}")
    f_rigid_true = truth_f(PAPER)
    drill = load(DRILL)
    synth = synthetic_loaded_log()
    lowpasses = [("none", None)] + ([(f"{cutoff:.1f} Hz", cutoff)] if cutoff else [])

    # warm-up (the kernels compile once; wall_time_s excludes it anyway)
    payload_run(drill.window(1.0, 1.2), prior, None)

    for name, log in (("drill_flex", drill), ("synthetic rigid loaded", synth)):
        for prior_name, pf in (("identified prior", prior), ("true unloaded f", f_rigid_true)):
            print(f"\n  {name}, {prior_name}: identified mass (kg) [wall s], true 1.5 kg")
            print(f"  {'window':>14s} " + " ".join(f"{lab + ' lp ' + ln:>24s}"
                                                  for lab in map(str, lengths)
                                                  for ln, _ in lowpasses))
            full = []
            for t0 in starts:
                cells = []
                for L in lengths:
                    if t0 + L > log.t[-1] + 1e-9:
                        cells += [f"{'-':>24s}"] * len(lowpasses)
                        continue
                    w = log.window(t0, t0 + L)
                    for _, lp in lowpasses:
                        m, wall = payload_run(w, pf, lp)
                        full.append(m)
                        cells.append(f"{m:>16.3f} [{wall:5.2f}]")
                print(f"  {'start ' + format(t0, '.2f') + ' s':>14s} " + " ".join(cells),
                      flush=True)
            cells = []
            for _, lp in lowpasses:
                m, wall = payload_run(log, pf, lp)
                cells.append(f"{m:.3f} kg [{wall:.2f} s] (lp {lp})")
            print(f"  {'whole log':>14s} " + "; ".join(cells), flush=True)
    # the paper's GA on the window output error, for the record
    print("\n  drill_flex [1.0, 1.2), identified prior, method='paper' (GA on the output error):")
    for _, lp in lowpasses:
        m, wall = payload_run(drill.window(1.0, 1.2), prior, lp, method="paper")
        print(f"    lowpass {lp}: {m:.3f} kg in {wall:.1f} s", flush=True)


def main(argv=None):
    """Run the selected sections."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sections", default=",".join(SECTIONS),
                   help=f"comma-separated subset of {','.join(SECTIONS)}")
    p.add_argument("--cutoffs", default="none,suggested,10,15",
                   help="drill cut-offs (Hz, 'none' or 'suggested')")
    p.add_argument("--starts", default="0.5,1.0,1.5,2.0,2.5",
                   help="window start times (s) of the payload section")
    p.add_argument("--lengths", default="0.2,0.4,0.8", help="window lengths (s)")
    p.add_argument("--out", type=Path, default=Path("out") / "bench_payload")
    args = p.parse_args(argv)
    sections = [s.strip() for s in args.sections.split(",") if s.strip()]
    unknown = set(sections) - set(SECTIONS)
    if unknown:
        p.error(f"unknown section(s): {', '.join(sorted(unknown))}")
    args.out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    print(f"compile/load kernels: {plant.warm_up():.1f} s; "
          f"numba threads: {os.environ.get('NUMBA_NUM_THREADS', 'default')}")
    cutoff = error_spectrum(load(DRILL)).cutoff_hz
    if "spectrum" in sections:
        cutoff = section_spectrum(args.out)
    if "drill" in sections:
        cutoffs = []
        for c in args.cutoffs.split(","):
            c = c.strip()
            if c == "none":
                cutoffs.append(("none", None))
            elif c == "suggested":
                cutoffs.append((f"sugg {cutoff:.1f}" if cutoff else "sugg none", cutoff))
            else:
                cutoffs.append((f"{float(c):g} Hz", float(c)))
        section_drill(cutoffs)
    if "coarse" in sections:
        section_coarse(args.out)
    if "payload" in sections:
        section_payload(cutoff, [float(s) for s in args.starts.split(",")],
                        [float(s) for s in args.lengths.split(",")])
    print(f"\ntotal {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
