"""Held-out flexible logs: identification accuracy of identify() (model='auto').

Emulates P-control logs with the two-mass plant (:class:`plant.FlexibleJoints`)
at settings other than the development logs' -- stiffness 5e3..5e4 N m/rad,
several dampings, payloads 0..4 kg (f changed by plant.add_payload),
encoders 250..4096 ppr, P gains -- identifies each with the default
``identify(log)`` and prints the relative error per parameter and the worst
case (the table of docs/tutorial_real_rigs.rst).

Run: ``python benchmarks/bench_flexible.py [--quick]`` (from the repository root).
"""
from __future__ import annotations

import dataclasses
import sys
import time

import numpy as np

import plant
from identification import identify

#: (K2, K3, D2, D3, payload kg, ppr2, ppr3, P gain)
CASES = [
    (5e3, 8e3, 1.0, 0.5, 0.0, 1000, 1000, 0.15),
    (2e4, 5e3, 8.0, 0.2, 2.0, 250, 250, 0.15),
    (5e4, 2e4, 2.0, 2.0, 4.0, 4096, 4096, 0.1),
    (1e4, 1e4, 0.5, 1.0, 1.0, 2000, 500, 0.2),
    (3e4, 5e3, 15.0, 0.1, 3.0, 500, 2048, 0.12),
    (8e3, 4e4, 4.0, 4.0, 0.5, 1024, 250, 0.18),
]

#: Motor rotor inertia of the emulated drives (kg m^2).
JM = 200e-6
F_UNLOADED = np.array([1.15, 0.58, 0.0, -0.52, 0.0, -1.2, 4.75, -0.1, 3.8])


def case_log(base, case, *, rng):
    """An emulated flexible log and its truth for one case."""
    k2, k3, d2, d3, mass, n2, n3, p = case
    f = plant.add_payload(F_UNLOADED, plant.Payload(mass, (0.05, 0.0), 0.002 * mass),
                          base.rig.a3_m)
    rig = dataclasses.replace(base.rig, encoder_ppr=(n2, n3), p_gain_A_per_pulse=(p, p))
    flex = plant.FlexibleJoints((k2, k3), (d2, d3), (JM, JM))
    log = plant.emulate_log(base, f, rig=rig, flexible=flex, current_noise_A=0.05, rng=rng,
                            name=f"flex_{int(k2)}_{int(k3)}")
    return log, f, np.array([k2, k3]), flex.reflected_inertia(rig)


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    cases = CASES[:2] if "--quick" in argv else CASES
    base = plant.load_example("paper_rigid")
    rng = np.random.default_rng(13)
    idx = [0, 1, 3, 5, 6, 8]
    rows = []
    for case in cases:
        log, f, K, jk = case_log(base, case, rng=rng)
        t0 = time.perf_counter()
        r = identify(log, rng=0, progress=False)
        dt = time.perf_counter() - t0
        ef = 100 * np.abs(r.f - f)[idx] / np.abs(f)[idx]
        if r.model == "flexible":
            eK = 100 * np.abs(np.asarray(r.joint_stiffness_Nm_per_rad) - K) / K
            eJ = 100 * np.abs(np.asarray(r.motor_inertia_reflected_kgm2) - jk) / jk
        else:
            eK = eJ = np.full(2, np.nan)
        rows.append(np.r_[ef, eK, eJ])
        print(f"{log.name:18s} ppr {case[5]}/{case[6]} P {case[7]} m {case[4]} kg: "
              f"model {r.model}, {dt:.0f} s; |df| % f1 f2 f4 f6 f7 f9 "
              + " ".join(f"{v:.2f}" for v in ef)
              + f"; K % {eK[0]:.1f} {eK[1]:.1f}; Jm k^2 % {eJ[0]:.1f} {eJ[1]:.1f}", flush=True)
    worst = np.nanmax(np.array(rows), axis=0)
    names = ["f1", "f2", "f4", "f6", "f7", "f9", "K2", "K3", "Jk2", "Jk3"]
    print("worst case %: " + ", ".join(f"{n} {v:.2f}" for n, v in zip(names, worst)))


if __name__ == "__main__":
    main()
