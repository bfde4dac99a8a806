"""Plant: rig logs, the PUMA 560 links 2-3 model and the closed-loop simulator.

Pipeline position: log + rig (:mod:`plant.log`, :mod:`plant.rig`) ->
model (:mod:`plant.model`, derived symbolically in :mod:`plant.symbolic`) ->
closed-loop simulation (:mod:`plant.simulate`).
"""
from ._errors import LogError, SimulationError
from .closed_loop import ClosedLoopResponse, FlexibleJoints, simulate_closed_loop
from .log import ExperimentLog, example_log_path, load_example, load_log
from .model import (
    coriolis_centrifugal,
    forward_dynamics,
    gravity_vector,
    inertia_matrix,
    inverse_dynamics,
    is_positive_definite,
    regressor,
)
from .plotting import plot_tracking_errors
from .payload import Payload, add_payload, payload_delta, recover_payload
from .rig import F_NAMES, F_UNITS, Rig
from .simulate import (
    DEFAULT_SUBSTEPS,
    ExperimentSimulation,
    output_error,
    prediction_errors,
    simulate_batch,
    simulate_experiment,
)
from .trajectory import Trajectory

__all__ = [
    "LogError",
    "SimulationError",
    "ExperimentLog",
    "load_log",
    "load_example",
    "example_log_path",
    "Rig",
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
    "DEFAULT_SUBSTEPS",
    "ExperimentSimulation",
    "simulate_experiment",
    "simulate_batch",
    "output_error",
    "prediction_errors",
    "plot_tracking_errors",
    "simulate_closed_loop",
    "ClosedLoopResponse",
    "FlexibleJoints",
]
