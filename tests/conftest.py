"""Shared fixtures: the FMUs are built (or taken from the cache) once per test session."""
from __future__ import annotations

from pathlib import Path

import pytest

from fmu_build import build_fmu


@pytest.fixture(scope="session")
def fmu2() -> Path:
    """Path of the FMI 2.0 co-simulation HarmonicDrive.fmu."""
    return build_fmu(fmi_version=2)


@pytest.fixture(scope="session")
def fmu3() -> Path:
    """Path of the FMI 3.0 co-simulation HarmonicDrive.fmu."""
    return build_fmu(fmi_version=3)


@pytest.fixture(scope="session", params=[2, 3], ids=["fmi2", "fmi3"])
def fmu_any(request) -> Path:
    return build_fmu(fmi_version=request.param)
