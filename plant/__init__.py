"""Plant: rig logs, the PUMA 560 links 2-3 model and the closed-loop simulator.

Pipeline position: log + rig (:mod:`plant.log`, :mod:`plant.rig`) ->
model (:mod:`plant.model`, derived symbolically in :mod:`plant.symbolic`) ->
closed-loop simulation: one core (:mod:`plant.core`) advancing a plant
(:mod:`plant.plants`, rigid or flexible), driven by the P experiment
(:mod:`plant.simulate`), the logged-input replay (:mod:`plant.replay`) and
the any-controller loop (:mod:`plant.closed_loop`).

Any serial arm (:mod:`plant.robot_model`): :class:`RobotModel` from a DH
table derives the dynamics, the regressor and the base parameters with
casadi; the PUMA 560 links 2-3 of the paper are one instance
(``RobotModel.puma560()``, whose torques are eq. 3's f1..f9).
"""
from ._errors import LogError, SimulationError
from .closed_loop import DEFAULT_CLOSED_LOOP_SUBSTEPS, simulate_closed_loop
from .core import STATUS_MESSAGES, STATUS_OK
from .log import ExperimentLog, as_log, example_log_path, load_example, load_log
from .model import (
    coriolis_centrifugal,
    forward_dynamics,
    gravity_vector,
    inertia_matrix,
    inverse_dynamics,
    is_positive_definite,
    regressor,
)
from .warmup import kernels_cached, warm_up
from .payload import Payload, add_payload, payload_delta, recover_payload
from .plants import RIGID, FlexibleJoints, Plant
from .friction import RIGID_FRICTION
from .plotting import plot_tracking_errors
from .replay import measured_counts, prediction_errors
from .response import ClosedLoopResponse
from .robot_model import Link, RobotModel
from .rig import F_NAMES, F_UNITS, Rig, RigConstants, rig_constants
from .synthetic import emulate_log
from .simulate import (
    DEFAULT_SUBSTEPS,
    ExperimentSimulation,
    SimulationInputs,
    output_error,
    simulate_batch,
    simulate_experiment,
    simulation_inputs,
)
from .trajectory import Trajectory

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
