"""Computed-torque control built on the identified model: the PUMA 560 links 2-3 and any serial arm.

* :mod:`ctc.protocol` -- the sampled-controller protocol and the paper's
  :class:`PController`;
* :mod:`ctc.computed_torque` -- :class:`ComputedTorqueController`;
* :mod:`ctc.flexible` -- :class:`FlexibleJointComputedTorqueController`
  (motor-side computed torque of a flexible-joint robot; what
  :meth:`ComputedTorqueController.from_result` builds from a flexible
  identification);
* :mod:`ctc.adaptive` -- :class:`AdaptiveComputedTorqueController` (on-line
  payload identification and adaptation);
* :mod:`ctc.arm` -- :class:`~ctc.arm.ArmComputedTorque` (any serial arm of a
  robot model; :class:`~ctc.arm.ArmFlexibleComputedTorque` for compliant joints);
* :mod:`ctc.arm_adaptive` -- :class:`~ctc.arm_adaptive.ArmAdaptiveComputedTorque`
  (any arm, its payload identified on-line from windows of its own run);
* :mod:`ctc.guard` -- :class:`FollowingErrorGuard` (a following-error
  limit around any controller: the rig's P law takes over when the arm is lost);
* :mod:`ctc.contract` -- :class:`IdentifiedModel` (the result -> controller
  contract: what every ``from_result`` reads from an identification);
* :mod:`ctc.design` -- gain design and analysis with python-control
  (:func:`design_gains`);
* :mod:`ctc.evaluate` -- closed-loop evaluation with casadi
  (:func:`evaluate_ctc`).

Run a controller against the model robot with
:func:`plant.simulation.closed_loop.simulate_closed_loop`.
"""
from .adaptive import AdaptiveComputedTorqueController, UnmodelledChangeWarning
from .computed_torque import ComputedTorqueController
from .contract import IdentifiedModel
from .design import GainDesign, design_gains
from .flexible import FlexibleJointComputedTorqueController
from .guard import FollowingErrorGuard, FollowingErrorWarning
from .protocol import PController, SampledController

__all__ = [
    "SampledController",
    "PController",
    "ComputedTorqueController",
    "IdentifiedModel",
    "AdaptiveComputedTorqueController", "UnmodelledChangeWarning",
    "FlexibleJointComputedTorqueController",
    "FollowingErrorGuard", "FollowingErrorWarning",
    "GainDesign",
    "design_gains",
    "evaluate_ctc",
    "CasadiEvaluation",
]


def __getattr__(name):
    # casadi evaluation imported lazily (builds symbolic graphs)
    if name in ("evaluate_ctc", "CasadiEvaluation"):
        from . import evaluate

        return getattr(evaluate, name)
    raise AttributeError(f"module 'ctc' has no attribute {name!r}")
