"""hdrive: resolution of harmonic-drive joints with stick-slip friction.

Public API:

- ``DriveParams``: SI drive parameters, the paper's non-dimensional groups (K*, J_l*, f_l*), the nominal drive.
- ``Plant``: the HarmonicDrive FMU (FMI 2.0 / 3.0 co-simulation, exact stick-slip) driven through fmpy.
"""
from .params import DriveParams, ParameterError
from .plant import Plant, PlantError, PlantState, Sample

__all__ = ["DriveParams", "ParameterError", "Plant", "PlantError", "PlantState", "Sample"]
__version__ = "0.1.0"
