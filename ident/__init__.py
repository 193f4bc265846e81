"""hdrive: resolution of harmonic-drive joints with stick-slip friction.

Public API:

- ``DriveParams``: SI drive parameters, the paper's non-dimensional groups (K*, J_l*, f_l*), the nominal drive.
- ``Plant``: the HarmonicDrive FMU (FMI 2.0 / 3.0 co-simulation, exact stick-slip) driven through fmpy.
- ``ImpulseController``, ``LinearPD``: the paper's two controllers, speaking to a ``Plant``.
- ``impulse_resolution(...)``, ``linear_resolution(...)``: the paper's resolution protocols.
"""
from .params import DriveParams, ParameterError
from .plant import Plant, PlantError, PlantState, Sample, SettleError
from .controllers import ImpulseController, LinearPD
from .resolution import (ImpulseResolution, LinearResolution, NoConsistentStep, ThresholdNotFound,
                         impulse_experiment, impulse_resolution, linear_resolution)

__all__ = ["DriveParams", "ImpulseController", "ImpulseResolution", "LinearPD", "LinearResolution",
           "NoConsistentStep", "ParameterError", "Plant", "PlantError", "PlantState", "Sample", "SettleError",
           "ThresholdNotFound", "impulse_experiment", "impulse_resolution", "linear_resolution"]
__version__ = "0.1.0"
