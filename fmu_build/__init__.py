"""Build the HarmonicDrive FMU (FMI 2.0 / 3.0 co-simulation) from the C sources in ``c/``.

``variables.py`` is the single variable table; ``build.py`` turns it into both modelDescription.xml files and a C
header, compiles the C model with the system compiler against fmpy's FMI headers, zips the FMU and caches it.
"""
from .build import build_fmu, default_fmu_path

__all__ = ["build_fmu", "default_fmu_path"]
