"""Per-identification wall time of the on-line payload identification (issue 14).

A held-out emulated run (2 kg payload) is cut into 100 ms windows (the
adaptive CTC's default, whose fixed latency is 0.1 s) and 200 ms windows
without a start state; each is identified with ``identify(..., payload=True)`` (P
control in the loop) and, for a CTC run of the same robot, with the CTC in
the loop (``controller=``).  Prints the wall time per identification
(kernels compiled; target: at most the window's length) and the
identified mass.

    python benchmarks/bench_online_payload.py
"""
from __future__ import annotations

import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import ctc  # noqa: E402
import identification  # noqa: E402
import plant  # noqa: E402

PRIOR = np.array([0.9385, 0.3618, 0.01087, -0.3860, 0.02538, -0.8942, 4.4358, -0.1040, 3.7952])


def main():
    """Print the table."""
    print(f"compile/load kernels: {plant.warm_up():.1f} s")
    base = plant.load_example()
    f = plant.add_payload(PRIOR, plant.Payload(2.0, (0.1, 0.02), 0.01), base.rig.a3_m)
    p_run = plant.emulate_log(base, f)
    c = ctc.ComputedTorqueController.from_log(PRIOR, base)
    r = plant.simulate_closed_loop(base, f, c, substeps=16)
    ctc_run = p_run.replace(e_pulses=r.e_pulses, i_A=r.i_A)
    print(f"{'run':<6s} {'window':>16s} {'wall s':>8s} {'mass kg':>8s}")
    walls = {0.1: [], 0.2: []}
    for name, log, ctl, length in (("P", p_run, None, 0.2), ("CTC", ctc_run, c, 0.2),
                                   ("P", p_run, None, 0.1), ("CTC", ctc_run, c, 0.1)):
        for t0 in np.arange(0.2, 3.4, 0.4):
            w = log.window(t0, t0 + length)
            w = w.replace(rig=dataclasses.replace(w.rig, q0_rad=None, qd0_rad_per_s=None))
            law = None if ctl is None else ctl.logged_controller(w)
            t = time.perf_counter()
            res = identification.identify(w, payload=True, prior=PRIOR, rng=0, progress=False,
                                          controller=law)
            walls[length].append(res.wall_time_s)
            print(f"{name:<6s} [{t0:.2f}, {t0 + length:.2f}) s {res.wall_time_s:8.3f} "
                  f"{res.payload['mass_kg']:8.3f}   (call {time.perf_counter() - t:.3f} s)")
    for length, ws in walls.items():
        print(f"wall time per identification, {1000 * length:.0f} ms windows: median "
              f"{np.median(ws):.3f} s, max {np.max(ws):.3f} s (target <= {length:g} s)")


if __name__ == "__main__":
    main()
