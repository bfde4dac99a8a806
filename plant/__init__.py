"""Plant: rig logs, the robot model and the closed-loop simulator.

Three subpackages, one per concern, in pipeline order:

* :mod:`plant.logs` -- the log and the rig: the CSV + JSON sidecar
  (:mod:`plant.logs.log`, :mod:`plant.logs.sidecar`, :mod:`plant.logs.arm_log`),
  the rig constants (:mod:`plant.logs.rig`), the reference
  (:mod:`plant.logs.trajectory`), atomic file writes and plots.
* :mod:`plant.robot` -- the robot model: :class:`RobotModel` from a DH table
  or a URDF (:mod:`plant.robot.robot_model`), its casadi derivation
  (:mod:`plant.robot.symbolic`), the numeric code generated from it
  (:mod:`plant.robot.codegen`), the PUMA 560 links 2-3 instance's closed forms
  (:mod:`plant.robot.model`, eq. 3's f1..f9) and payloads.
* :mod:`plant.simulation` -- the closed-loop simulator: one sample-step core
  (:mod:`plant.simulation.core`) advancing a plant's right-hand side
  (:mod:`plant.simulation.plants`, rigid or flexible, with friction and
  backlash), driven by the P experiment (:mod:`plant.simulation.simulate`),
  the logged-input replay (:mod:`plant.simulation.replay`), the
  any-controller loop (:mod:`plant.simulation.closed_loop`) and the n-joint
  arm driver (:mod:`plant.simulation.arm`).

The public names are re-exported here (``from plant import ExperimentLog``).
The flat module paths of version 0.1 (``plant.log``, ``plant.simulate``, ...)
still import, with a :class:`DeprecationWarning` naming the new path.
"""
from ._errors import LogError, SimulationError
from .simulation.closed_loop import DEFAULT_CLOSED_LOOP_SUBSTEPS, simulate_closed_loop
from .simulation.core import STATUS_MESSAGES, STATUS_OK
from .logs.log import ExperimentLog, as_log, example_log_path, load_example, load_log
from .robot.model import (
    coriolis_centrifugal,
    forward_dynamics,
    gravity_vector,
    inertia_matrix,
    inverse_dynamics,
    is_positive_definite,
    regressor,
)
from .simulation.warmup import kernels_cached, warm_up
from .robot.payload import Payload, add_payload, payload_delta, recover_payload
from .simulation.plants import RIGID, FlexibleJoints, Plant
from .simulation.friction import RIGID_FRICTION
from .logs.plotting import plot_tracking_errors
from .simulation.replay import measured_counts, prediction_errors
from .simulation.response import ClosedLoopResponse
from .robot.robot_model import Link, RobotModel
from .logs.rig import F_NAMES, F_UNITS, Rig, RigConstants, rig_constants
from .simulation.synthetic import emulate_log
from .simulation.simulate import (
    DEFAULT_SUBSTEPS,
    ExperimentSimulation,
    SimulationInputs,
    output_error,
    simulate_batch,
    simulate_experiment,
    simulation_inputs,
)
from .logs.trajectory import Trajectory

__all__ = [
    "RobotModel",
    "Link",
    "LogError",
    "SimulationError",
    "ExperimentLog",
    "load_log",
    "as_log",
    "load_example",
    "example_log_path",
    "Rig",
    "RigConstants",
    "rig_constants",
    "F_NAMES",
    "F_UNITS",
    "Trajectory",
    "inertia_matrix",
    "coriolis_centrifugal",
    "gravity_vector",
    "inverse_dynamics",
    "forward_dynamics",
    "regressor",
    "is_positive_definite",
    "Payload",
    "add_payload",
    "payload_delta",
    "recover_payload",
    "Plant",
    "RIGID",
    "FlexibleJoints",
    "RIGID_FRICTION",
    "STATUS_OK",
    "STATUS_MESSAGES",
    "DEFAULT_SUBSTEPS",
    "DEFAULT_CLOSED_LOOP_SUBSTEPS",
    "ExperimentSimulation",
    "SimulationInputs",
    "simulation_inputs",
    "simulate_experiment",
    "simulate_batch",
    "output_error",
    "prediction_errors",
    "measured_counts",
    "plot_tracking_errors",
    "simulate_closed_loop",
    "ClosedLoopResponse",
    "emulate_log",
    "warm_up",
    "kernels_cached",
]


def _install_flat_aliases():
    """Let the 0.1 flat paths (``plant.log`` ...) import their new modules.

    A :class:`importlib.abc.MetaPathFinder` maps ``plant.<module>`` to
    ``plant.<subpackage>.<module>`` (warning once per import), the way
    scipy keeps deprecated submodule paths importable.
    """
    import importlib
    import importlib.abc
    import importlib.util
    import sys
    import warnings

    moved = {
        "logs": ("log", "arm_log", "rig", "sidecar", "fileio", "sanity", "trajectory", "plotting"),
        "robot": ("robot_model", "model", "symbolic", "codegen", "payload"),
        "simulation": ("core", "anchors", "plants", "friction", "arm", "lanes", "parallel",
                       "simulate", "replay", "closed_loop", "controllers", "twin", "response",
                       "synthetic", "warmup"),
    }
    home = {f"{__name__}.{m}": f"{__name__}.{g}.{m}" for g, ms in moved.items() for m in ms}

    class _Alias(importlib.abc.Loader):
        def __init__(self, target):
            self.target = target

        def create_module(self, spec):
            warnings.warn(f"{spec.name} moved to {self.target}", DeprecationWarning, stacklevel=3)
            return importlib.import_module(self.target)

        def exec_module(self, module):
            pass

    class _Finder(importlib.abc.MetaPathFinder):
        def find_spec(self, fullname, path=None, target=None):
            if fullname not in home:
                return None
            return importlib.util.spec_from_loader(fullname, _Alias(home[fullname]))

    sys.meta_path.append(_Finder())


_install_flat_aliases()
