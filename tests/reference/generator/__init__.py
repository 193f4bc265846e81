"""Independent generator of randomized "measured" drive logs with known truth (no code shared with the product).

Public API (see ``logs.py``): ``identification_case``, ``diagnosis_case``, ``sized_case``, ``clean_case``,
``two_effect_case``, ``outside_library_case`` -> ``GeneratedLog`` (``.write(dir)`` in the product's file format,
``.truth``); the suites ``IDENTIFICATION_SUITE``, ``IDENTIFICATION_SLOW_SUITE``, ``DIAGNOSIS_MATRIX``,
``CLEAN_SUITE``, ``TWO_EFFECT_SUITE_SEEDS``, ``OUTSIDE_LIBRARY_SUITE``; the physics (``plant.py``: ``Drive``, ``Effects`` and the
effect shapes), the engines (``engines.py``, ``linear.py``), the excitations (``excitations.py``) and the effect
families with their magnitude search (``effects.py``).
"""
from .effects import CLASSES, LIBRARY_EFFECTS, OUTSIDE_LIBRARY_EFFECTS, VARIANTS
from .logs import (
                   CLEAN_SUITE,
                   DIAGNOSIS_MATRIX,
                   IDENTIFICATION_KINDS,
                   IDENTIFICATION_SLOW_SUITE,
                   IDENTIFICATION_SUITE,
                   IDENTIFICATION_SUITE_SEEDS,
                   OUTSIDE_LIBRARY_SUITE,
                   SIDECAR_KEYS,
                   TWO_EFFECT_SUITE_SEEDS,
                   GeneratedLog,
                   Truth,
                   clean_case,
                   diagnosis_case,
                   identification_case,
                   outside_library_case,
                   sized_case,
                   two_effect_case,
)
from .plant import (
                   CubicStiffness,
                   Dahl,
                   Drive,
                   Effects,
                   FrictionRipple,
                   KinematicError,
                   MaxwellSlip,
                   Stribeck,
                   ThreeSlopeStiffness,
)

__all__ = [
                   "CLASSES",
                   "CLEAN_SUITE",
                   "DIAGNOSIS_MATRIX",
                   "IDENTIFICATION_KINDS",
                   "IDENTIFICATION_SLOW_SUITE",
                   "IDENTIFICATION_SUITE",
                   "IDENTIFICATION_SUITE_SEEDS",
                   "LIBRARY_EFFECTS",
                   "OUTSIDE_LIBRARY_EFFECTS",
                   "OUTSIDE_LIBRARY_SUITE",
                   "SIDECAR_KEYS",
                   "TWO_EFFECT_SUITE_SEEDS",
                   "VARIANTS",
                   "CubicStiffness",
                   "Dahl",
                   "Drive",
                   "Effects",
                   "FrictionRipple",
                   "GeneratedLog",
                   "KinematicError",
                   "MaxwellSlip",
                   "Stribeck",
                   "ThreeSlopeStiffness",
                   "Truth",
                   "clean_case",
                   "diagnosis_case",
                   "identification_case",
                   "outside_library_case",
                   "sized_case",
                   "two_effect_case",
]
