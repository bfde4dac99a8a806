"""Your robot: a DH table -> its dynamics, regressor and base parameters.

Builds four arms with :class:`plant.RobotModel` and prints, for each, the
number of standard and base inertial parameters and the base parameters'
expressions (numerical QR, Gautier 1990):

* a two-link arm in a vertical plane (its DH table written here);
* the PUMA 560 links 2-3 of the paper (joint 1 and the wrist locked at 0),
  with the paper's f1..f9 (eq. 3) in the standard parameters and the two
  relations the geometry imposes on them;
* the PUMA 560 joints 1-3 (Corke's parameters, wrist locked);
* the six-joint PUMA 560;
* a three-joint arm with a tool on a fixed flange, from a URDF file
  (``--urdf``, default the repository's ``tests/data/urdf/arm_3r_tool.urdf``;
  needs the ``urdf`` extra, Robotics Toolbox for Python, else it is skipped).

Everything goes to ``out/your_robot/base_parameters.json``;
``docs/tutorial_your_robot.rst`` quotes this script's output.

Run from the repository root (seconds)::

    python examples/your_robot.py
    python examples/your_robot.py --quick      # the same, without the six-joint arm

A bad option ends with one line ``error: ...`` and exit status 1.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def parse(argv):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="skip the six-joint arm")
    p.add_argument("--urdf", type=Path,
                   default=Path(__file__).resolve().parents[1] / "tests" / "data" / "urdf"
                   / "arm_3r_tool.urdf", help="a URDF file of a serial revolute chain")
    p.add_argument("--out", type=Path, default=Path("out") / "your_robot",
                   help="output directory (default out/your_robot)")
    return p.parse_args(argv)


def planar_arm():
    """A 2R arm in a vertical plane: 1.0 m and 0.8 m links, COM mid-link, geared motors."""
    from plant import RobotModel

    table = [  # standard DH: a, alpha, d, offset; then the link and its drive
        dict(a=1.0, alpha=0.0, d=0.0, mass=2.0, com=(-0.5, 0, 0),
             inertia=(0.01, 0.1, 0.17, 0, 0, 0), gear_ratio=50, motor_inertia=1e-4),
        dict(a=0.8, alpha=0.0, d=0.0, mass=1.5, com=(-0.4, 0, 0),
             inertia=(0.01, 0.06, 0.08, 0, 0, 0), gear_ratio=30, motor_inertia=1e-4),
    ]
    return RobotModel.from_dh(table, gravity=(0.0, -9.81, 0.0), name="planar 2R arm")


def describe(model, basis=None):
    t0 = time.perf_counter()
    base = model.base_parameters()
    wall = time.perf_counter() - t0
    out = dict(model=repr(model), n_joints=model.n_joints,
               n_standard=len(model.standard_parameter_names), n_base=base.rank,
               base=dict(zip(base.names, base.expressions)),
               base_values=dict(zip(base.names, base(model.standard_parameters()).tolist())),
               base_parameters_time_s=wall)
    print(f"{model!r}: {out['n_standard']} standard parameters, {base.rank} base parameters "
          f"({wall:.2f} s)")
    if model.n_joints <= 3:
        for name, expr in zip(base.names, base.expressions):
            print(f"  {name:6s} = {expr}")
    if basis is not None:
        named = model.express(basis)
        values = named(model.standard_parameters())
        out["named_basis"] = dict(name=basis.name, rank=named.rank, relations=list(named.relations),
                                  expressions=dict(zip(named.names, named.expressions)),
                                  values=dict(zip(named.names, values.tolist())))
        print(f"  in the basis '{basis.name}' ({len(named.names)} parameters, rank {named.rank}):")
        for name, expr, v in zip(named.names, named.expressions, values):
            print(f"  {name:3s} = {v:+.5f} = {expr}")
        for rel in named.relations:
            print(f"  relation: {rel}")
    return out


def main(argv=None):
    args = parse(argv)
    from plant import RobotModel
    from plant.robot.robot_model import PUMA560_LINKS23_BASIS

    report = {}
    report["planar"] = describe(planar_arm())
    report["puma_links23"] = describe(RobotModel.puma560(), PUMA560_LINKS23_BASIS)
    report["puma_joints123"] = describe(RobotModel.puma560(active=(0, 1, 2)))
    if not args.quick:
        report["puma_six_joints"] = describe(RobotModel.puma560(active=range(6)))
    try:
        import roboticstoolbox  # noqa: F401  (the urdf extra)
    except ImportError:
        print("URDF: skipped (pip install 'puma-ga-ctc[urdf]' for Robotics Toolbox's reader)")
    else:
        if args.urdf.is_file():
            report["urdf"] = describe(RobotModel.from_urdf(args.urdf))
        else:
            print(f"URDF: skipped (no file {args.urdf})")
    try:
        args.out.mkdir(parents=True, exist_ok=True)
        path = args.out / "base_parameters.json"
        tmp = path.with_suffix(".json.tmp")
        tmp.write_text(json.dumps(report, indent=1) + "\n")
        tmp.replace(path)
    except OSError as exc:
        print(f"error: cannot write {args.out}: {exc.strerror or exc}", file=sys.stderr)
        return 1
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except KeyboardInterrupt:
        sys.exit(130)
    except (ValueError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        sys.exit(1)
