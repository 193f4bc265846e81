"""Export a fitted drive as an FMU whose start values are the fitted parameters.

The FMU is built from the project's C sources with the variable table's start values replaced by the given
parameters, so the compiled defaults and both the modelDescription's start attributes agree (an importer that sets
nothing simulates the fitted drive).
"""
from __future__ import annotations

import shutil
from pathlib import Path

from .params import DriveParams


def export_fitted_fmu(params: DriveParams, path: str | Path, fmi_version: int = 2) -> Path:
    """Write ``path`` (.fmu): the HarmonicDrive FMU with ``params`` as start values."""
    from fmu_build import build_fmu

    path = Path(path)
    if path.suffix != ".fmu":
        raise ValueError(f"{path}: an FMU file name must end in .fmu")
    built = build_fmu(fmi_version=fmi_version, starts=params.to_dict())
    path.parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(built, path)
    return path
