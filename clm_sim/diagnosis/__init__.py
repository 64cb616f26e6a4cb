"""Diagnosis: show where a simulation disagrees with a measured record, name the physical cause
from the effect library, extend the model and measure the out-of-sample gain."""

from clm_sim.diagnosis.diagnose import Diagnosis, diagnose
from clm_sim.diagnosis.model import SimulationModel, load_model
from clm_sim.diagnosis.residual import DiagnosisSettings

__all__ = ["Diagnosis", "DiagnosisSettings", "SimulationModel", "diagnose", "load_model"]
