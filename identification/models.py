"""Result entries that say which model was identified: rigid or flexible, friction.

Every :class:`~identification.result.IdentificationResult` carries these keys
(:data:`MODEL_KEYS`, a JSON contract): ``model`` (``"rigid"`` or
``"flexible"``), ``joint_stiffness_Nm_per_rad``, ``joint_damping_Nms_per_rad``
and ``motor_inertia_reflected_kgm2`` (2 values each, ``None`` for a rigid
result), ``joint_backlash_rad`` (2 gearbox backlash widths, rad, ``None`` when
none is significant or the model is rigid), ``stage_times_s`` (seconds spent
in compilation, the search, the model choice with the flexible fits, and
the restarts of a failed search), ``viscous_friction_Nms_per_rad`` (2) and ``coulomb_friction_Nm``
(2 x 2) -- identified, or echoed from the sidecar -- with
``friction_identified``, and ``model_choice`` (how ``model`` was chosen, see
:mod:`identification.flexible`; None when it was not a choice), and
``joint_intervals`` (a flexible result's ranges of each joint's stiffness, damping
and reflected motor inertia whose prediction-error cost stays within a tenth of a
quantisation floor of the fit's, and the robots the log allows beside the fit,
:func:`identification.flexible.joint_intervals`; None for a rigid result).
"""
from __future__ import annotations

from .friction import friction_entries

__all__ = ["MODEL_KEYS", "result_entries"]

#: Keys every result carries (see the module docstring).
MODEL_KEYS = ("model", "joint_stiffness_Nm_per_rad", "joint_damping_Nms_per_rad",
              "motor_inertia_reflected_kgm2", "joint_backlash_rad", "stage_times_s",
              "viscous_friction_Nms_per_rad", "coulomb_friction_Nm", "friction_identified",
              "model_choice", "at_bounds", "joint_intervals")


def result_entries(space, x, log) -> dict:
    """The model keys of a result, then the parameterisation's extras over them.

    Parameters
    ----------
    space : identification.parameters.Parameterisation
        The searched parameterisation.
    x : ndarray, shape (k,)
        The identified vector.
    log : plant.ExperimentLog

    Returns
    -------
    dict
        A rigid model with the sidecar's friction unless ``space.extras``
        says otherwise.
    """
    out = dict(model="rigid", joint_stiffness_Nm_per_rad=None, joint_damping_Nms_per_rad=None,
               motor_inertia_reflected_kgm2=None, joint_backlash_rad=None, model_choice=None,
               joint_intervals=None)
    out.update(friction_entries(log))
    out.update(space.extras(x, log))
    return out
