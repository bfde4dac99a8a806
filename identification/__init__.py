"""Identification of the base parameters f1..f9 from position-only logs.

Pipeline position: objective (output error of paper eq. 4, on the plant's
closed-loop simulator) + optimiser (the paper's multi-population GA, then
prediction-error refinement) -> :class:`IdentificationResult`.
"""
from .api import DEFAULT_METHOD, METHODS, identify
from .distributed import Job, JobResult, identify_many, seed_jobs
from .filtering import apply_lowpass, lowpass_sos
from .ga import GAResult, run_ga
from .objective import IDENTIFICATION_SUBSTEPS, OutputError
from .parameters import (
    DEFAULT_PAYLOAD_BOUNDS,
    BaseParameters,
    ConsistentBaseParameters,
    Parameterisation,
    PayloadParameters,
)
from .refine import PredictionErrorProblem, RefineResult, refine
from .result import IdentificationResult

__all__ = [
    "identify",
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


def __getattr__(name):
    # imported on first use, so ``python -m identification.excitation`` runs the
    # module without a second copy in sys.modules
    if name == "design_excitation":
        from .excitation import design_excitation

        return design_excitation
    raise AttributeError(f"module 'identification' has no attribute {name!r}")
