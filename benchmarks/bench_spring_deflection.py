"""How far a drawn tool bends the compliant draws' springs (issue 21, arm path).

For each compliant ``planar2`` draw of ``benchmarks/independent_arm.py``
(seeds ``seed + i``) and the tool ``benchmarks/bench_arm_payload.py`` draws
for it, the quasi-static deflection of each joint's spring that the tool
adds, ``|g_loaded(q) - g(q)| / K`` in motor-encoder pulses (``k N / 2 pi``
per joint radian), over random arm angles (the gravity torques from the
independent simulator's own dynamics, Robotics Toolbox ``rne``; no library
code).  A pick-up or a put-down leaves the links ringing by about as much:
the size the link start box of a two-mass window's fit must hold
(:mod:`identification.arm_payload`) -- for a fit whose payload is not the
robot's (the model in use pinned across a change, a rival); a fit with the
right payload starts its links at the sag already.  The angles are drawn
over the full circle, not along a trajectory.

Usage::

    python benchmarks/bench_spring_deflection.py --seeds 20261841 20261861 20261871 20261881 20261891 --n 6

Prints one line per compliant draw (tool mass, stiffness, largest and median
deflection per joint) and how many draws exceed 100 pulses on some joint.
Needs the ``bench`` extra (Robotics Toolbox).
"""
from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import independent_arm as ia  # noqa: E402
from bench_arm_payload import draw_payload  # noqa: E402


def deflections(seed: int, angles: np.ndarray):
    """``(settings, tool, pulses (n_angles, n))`` of a compliant planar draw, or None."""
    s = ia.draw("planar2", seed, compliant=True)
    if not s.compliant:
        return None
    tool = draw_payload(seed)
    bare = ia.IndependentArm(s)
    loaded = ia.IndependentArm(dataclasses.replace(s, payload=tool))
    zero = np.zeros(bare.n)
    out = [np.abs(loaded.dynamics(q, zero)[1] - bare.dynamics(q, zero)[1]) / bare.K
           * np.abs(bare.spr) for q in angles]
    return s, tool, np.array(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", required=True, help="first seed of each run")
    ap.add_argument("--n", type=int, default=6, help="draws per seed (seed + 0 .. n - 1)")
    ap.add_argument("--angles", type=int, default=20, help="random arm angles per draw")
    args = ap.parse_args(argv)
    if args.n < 1 or args.angles < 1:
        ap.error("--n and --angles must be >= 1")
    angles = np.random.default_rng(0).uniform(-np.pi, np.pi, (args.angles, 2))
    total = over = 0
    for first in args.seeds:
        for seed in range(first, first + args.n):
            got = deflections(seed, angles)
            if got is None:
                continue
            s, tool, d = got
            total += 1
            over += bool(d.max() > 100.0)
            print(f"planar2  {seed}  tool {tool['mass_kg']:.2f} kg  K "
                  f"{np.round(s.stiffness).astype(int).tolist()} N m/rad  deflection max "
                  f"{np.round(d.max(axis=0)).astype(int).tolist()}  median "
                  f"{np.round(np.median(d, axis=0)).astype(int).tolist()} pulses")
    print(f"\n{over} of {total} compliant draws deflect a spring by more than 100 pulses "
          f"(at some of {args.angles} random arm angles)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
