"""Identification of the base parameters f1..f9 from position-only logs.

Pipeline position: objective (output error of paper eq. 4, on the plant's
closed-loop simulator) + optimiser (the paper's multi-population GA, then
prediction-error refinement) -> :class:`IdentificationResult`.
"""
import importlib

# Where each public name lives.  The package imports its modules on first
# use (PEP 562), so that ``import identification`` -- and ``python -m
# identification`` before the command line takes over -- does not spend a
# second importing scipy and numba before anything can answer a Ctrl-C.
_LOCATIONS = {
    "identify": "api", "METHODS": "api", "DEFAULT_METHOD": "api",
    "ModelInadequacyWarning": "api",
    "SearchBoundWarning": "api",
    "identify_many": "distributed", "Job": "distributed", "JobResult": "distributed",
    "seed_jobs": "distributed",
    "apply_lowpass": "filtering", "lowpass_sos": "filtering",
    "GAResult": "ga", "GASolver": "ga", "run_ga": "ga",
    "IDENTIFICATION_SUBSTEPS": "objective", "OutputError": "objective",
    "DEFAULT_PAYLOAD_BOUNDS": "parameters", "BaseParameters": "parameters",
    "ConsistentBaseParameters": "parameters", "Parameterisation": "parameters",
    "PayloadParameters": "parameters",
    "PredictionErrorProblem": "refinement", "RefineResult": "refinement", "refine": "refinement",
    "IdentificationResult": "result",
    # python -m identification.excitation runs that module without a second copy
    "design_excitation": "excitation",
}


def __getattr__(name):
    module = _LOCATIONS.get(name)
    if module is None:
        raise AttributeError(f"module 'identification' has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{module}", __name__), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(_LOCATIONS))


__all__ = [
    "identify",
    "ModelInadequacyWarning",
    "SearchBoundWarning",
    "identify_many",
    "Job",
    "JobResult",
    "seed_jobs",
    "METHODS",
    "DEFAULT_METHOD",
    "IdentificationResult",
    "OutputError",
    "IDENTIFICATION_SUBSTEPS",
    "run_ga",
    "GASolver",
    "GAResult",
    "Parameterisation",
    "BaseParameters",
    "ConsistentBaseParameters",
    "PayloadParameters",
    "DEFAULT_PAYLOAD_BOUNDS",
    "PredictionErrorProblem",
    "RefineResult",
    "refine",
    "lowpass_sos",
    "apply_lowpass",
    "design_excitation",
]

