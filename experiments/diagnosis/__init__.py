"""Diagnosis: show where a simulation disagrees with a measured record, name the physical cause
from the effect library, extend the model and measure the out-of-sample gain."""

from experiments.diagnosis.diagnose import Diagnosis, diagnose
from experiments.diagnosis.residual import DiagnosisSettings

__all__ = ["Diagnosis", "DiagnosisSettings", "diagnose"]
