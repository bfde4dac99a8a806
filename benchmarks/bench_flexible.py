"""Held-out flexible logs: rigid vs flexible model vs IDIM-LS, and the CTC built from each.

Emulates P-control logs with the two-mass plant (:class:`plant.FlexibleJoints`)
at settings other than the development logs' -- stiffness 5e3..5e4 N m/rad,
several dampings, payloads 0..4 kg (f changed by plant.add_payload),
encoders 250..4096 ppr, P gains -- and for each log

* identifies it with the default ``identify(log)`` (``model="auto"``), whose
  flexible result also holds the rigid model's f (``rigid_f``: the rigid
  identification it started from, what ``model="rigid"`` returns), and with
  the classical ``identify(log, method="idim-ls")``;
* prints the relative error of the well-excited f1 f2 f4 f6 f7 f9 per model
  and the worst case over the logs (the comparison table of
  ``docs/tutorial_real_rigs.rst``), and the identified K, D, Jm k^2;
* builds the CTC from each result (``ComputedTorqueController.from_result``;
  the rigid and IDIM-LS ones are rigid CTCs) and runs it on the true
  flexible robot along the log's trajectory
  (``plant.simulate_closed_loop(..., flexible=...)``): max abs(e) in pulses
  after 0.1 s, joint 2 / joint 3.

With ``--drill`` it also identifies ``puma560_paper_drill_flex`` (truth from
``tests/data``, ``PUMA_DATA_DIR`` overrides) and runs the CTCs on its
two-mass robot.

Run: ``python benchmarks/bench_flexible.py [--quick] [--drill] [--json OUT.json]``
(from the repository root; about 1.5 min per log on 2 busy cores).
"""
from __future__ import annotations

import dataclasses
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

import plant
from ctc import ComputedTorqueController
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
#: Well-excited components reported (f1 f2 f4 f6 f7 f9).
IDX = [0, 1, 3, 5, 6, 8]
AFTER_S = 0.1


def case_log(base, case, *, rng):
    """An emulated flexible log, its true f, joints and plant for one case."""
    k2, k3, d2, d3, mass, n2, n3, p = case
    f = plant.add_payload(F_UNLOADED, plant.Payload(mass, (0.05, 0.0), 0.002 * mass),
                          base.rig.a3_m)
    rig = dataclasses.replace(base.rig, encoder_ppr=(n2, n3), p_gain_A_per_pulse=(p, p))
    flex = plant.FlexibleJoints((k2, k3), (d2, d3), (JM, JM))
    log = plant.emulate_log(base, f, rig=rig, flexible=flex, current_noise_A=0.05, rng=rng,
                            name=f"flex_{int(k2)}_{int(k3)}")
    return log, f, flex


def ctc_error(log, f_true, flex, controller):
    """Max abs(e) (pulses) after AFTER_S of ``controller`` on the true flexible robot."""
    r = plant.simulate_closed_loop(log, f_true, controller, flexible=flex)
    k = r.t >= AFTER_S
    if not r.success:
        return [float("nan")] * 2
    return [int(v) for v in np.abs(r.e_pulses[k]).max(axis=0)]


def evaluate(log, f, flex):
    """Identify ``log`` three ways and run the CTC of each on the true robot."""
    K = np.asarray(flex.stiffness_Nm_per_rad)
    D = np.asarray(flex.damping_Nms_per_rad)
    jk = flex.reflected_inertia(log.rig)
    t0 = time.perf_counter()
    auto = identify(log, rng=0, progress=False)
    t_auto = time.perf_counter() - t0
    idim = identify(log, method="idim-ls", progress=False)
    f_rigid = np.asarray(auto.get("rigid_f") if auto.model == "flexible" else auto.f, float)
    rel = lambda g: (100 * np.abs(np.asarray(g, float)[IDX] - f[IDX]) / np.abs(f[IDX])).tolist()
    row = dict(log=log.name, model=auto.model, wall_s=t_auto,
               err_rigid=rel(f_rigid), err_idim=rel(idim.f),
               err_flexible=rel(auto.f) if auto.model == "flexible" else None,
               true_K=K.tolist(), true_D=D.tolist(), true_Jk2=jk.tolist())
    if auto.model == "flexible":
        row.update(K=auto.joint_stiffness_Nm_per_rad, D=auto.joint_damping_Nms_per_rad,
                   Jk2=auto.motor_inertia_reflected_kgm2,
                   err_K=(100 * np.abs(np.asarray(auto.joint_stiffness_Nm_per_rad) - K) / K).tolist(),
                   err_Jk2=(100 * np.abs(np.asarray(auto.motor_inertia_reflected_kgm2) - jk)
                            / jk).tolist())
    row["ctc_true_f_rigid"] = ctc_error(log, f, flex, ComputedTorqueController.from_log(f, log))
    row["ctc_idim"] = ctc_error(log, f, flex, ComputedTorqueController.from_result(idim, log))
    row["ctc_rigid"] = ctc_error(log, f, flex, ComputedTorqueController.from_log(f_rigid, log))
    row["ctc_from_result"] = ctc_error(log, f, flex, ComputedTorqueController.from_result(auto, log))
    return row


def show(row):
    """One block of lines per log."""
    fmt = lambda v: "  ".join(f"{x:6.2f}" for x in v)
    print(f"{row['log']}: model {row['model']} ({row['wall_s']:.0f} s)")
    print(f"   |df| % f1 f2 f4 f6 f7 f9   rigid    {fmt(row['err_rigid'])}")
    if row["err_flexible"] is not None:
        print(f"                              flexible {fmt(row['err_flexible'])}")
    print(f"                              IDIM-LS  {fmt(row['err_idim'])}")
    if row["model"] == "flexible":
        print(f"   K {np.round(row['K'], 0).tolist()} (true {row['true_K']}, "
              f"err % {np.round(row['err_K'], 2).tolist()}); D {np.round(row['D'], 2).tolist()} "
              f"(true {row['true_D']}); Jm k^2 err % {np.round(row['err_Jk2'], 2).tolist()}")
    print(f"   CTC max|e| after {AFTER_S} s: rigid CTC true f {row['ctc_true_f_rigid']}, "
          f"IDIM-LS {row['ctc_idim']}, rigid model {row['ctc_rigid']}, "
          f"from_result {row['ctc_from_result']}", flush=True)


def drill_case():
    """The development drill/flex log with its truth file's emulator constants."""
    data = Path(os.environ.get("PUMA_DATA_DIR", Path(__file__).resolve().parents[1] / "tests" / "data"))
    stem = "puma560_paper_drill_flex"
    log = plant.load_log(data / f"{stem}.csv")
    tr = json.loads((data / f"{stem}.truth.json").read_text())
    v = tr["emulator"]["variant"]
    flex = plant.FlexibleJoints(tuple(v["flex_stiffness"]), tuple(v["flex_damping"]), JM)
    return log, np.asarray(tr["f_vector"], float), flex


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    cases = CASES[:2] if "--quick" in argv else CASES
    base = plant.load_example("paper_rigid")
    rng = np.random.default_rng(13)
    rows = []
    for case in cases:
        log, f, flex = case_log(base, case, rng=rng)
        rows.append(evaluate(log, f, flex))
        show(rows[-1])
    worst = {k: np.nanmax([r[k] for r in rows if r[k] is not None], axis=0).tolist()
             for k in ("err_rigid", "err_flexible", "err_idim", "err_K", "err_Jk2",
                       "ctc_true_f_rigid", "ctc_idim", "ctc_rigid", "ctc_from_result")
             if any(r.get(k) is not None for r in rows)}
    print("\nworst case over the held-out logs:")
    for k, v in worst.items():
        print(f"  {k:18s} " + " ".join(f"{x:.2f}" for x in v))
    out = dict(cases=rows, worst=worst)
    if "--drill" in argv:
        log, f, flex = drill_case()
        out["drill"] = evaluate(log, f, flex)
        show(out["drill"])
    if "--json" in argv:
        path = Path(argv[argv.index("--json") + 1])
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(out, indent=1, default=float))


if __name__ == "__main__":
    main()
