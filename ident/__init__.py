"""hdrive: resolution of harmonic-drive joints with stick-slip friction.

Public API (``from ident import ...``):

- the model: ``DriveParams`` (SI drive parameters, the paper's non-dimensional groups K*, J_l*, f_l*, the nominal
  drive), ``Plant`` (the HarmonicDrive FMU, FMI 2.0 / 3.0 co-simulation with exact stick-slip, driven through
  fmpy);
- the protocols: ``ImpulseController``, ``LinearPD`` (the paper's two controllers, speaking to a ``Plant``, for
  loops you write), ``impulse_resolution``, ``linear_resolution``, ``impulse_experiment`` and ``friction_sweep``
  (their inner loops compiled over the FMU's functions by default, ``loop="python"`` for the controllers above);
- fitting: ``read_log`` / ``write_log`` (``DriveLog``), ``identify`` (K*, J_l*, f_l* of a two-inertia log, or the
  rigid model), ``predict`` (resolution of a fitted drive with an interval);
- diagnosis: ``diagnose`` (which effects the base model misses).

The subpackages are the product's parts: ``ident.model``, ``ident.protocols``, ``ident.fitting``,
``ident.diagnosis``, ``ident.studies`` (the paper study, the paper-effects study, EMPS) and ``ident.common``.
"""
from __future__ import annotations

import importlib
from typing import Any

from .model.params import DriveParams, ParameterError
from .model.plant import Plant, PlantError, PlantState, Sample, SettleError
from .protocols.controllers import ImpulseController, LinearPD
from .protocols.resolution import (
    ImpulseResolution,
    LinearResolution,
    NoConsistentStep,
    ThresholdNotFound,
    impulse_experiment,
    impulse_resolution,
    linear_resolution,
)

# Imported on first use: they pull in CasADi and SciPy's optimisation and statistics.
_LAZY = {"DriveLog": "fitting.logs", "LogError": "fitting.logs", "read_log": "fitting.logs", "write_log": "fitting.logs",
         "identify": "fitting.identify", "TwoInertiaFit": "fitting.identify", "predict": "fitting.predict",
         "Prediction": "fitting.predict", "diagnose": "diagnosis.engine", "Diagnosis": "diagnosis.result",
         "FrictionSweep": "protocols.sweep", "friction_sweep": "protocols.sweep"}

__all__ = ["DriveParams", "ImpulseController", "ImpulseResolution", "LinearPD", "LinearResolution",
           "NoConsistentStep", "ParameterError", "Plant", "PlantError", "PlantState", "Sample", "SettleError",
           "ThresholdNotFound", "impulse_experiment", "impulse_resolution", "linear_resolution", *sorted(_LAZY)]
__version__ = "0.1.0"


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        value = getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'ident' has no attribute {name!r}")
