"""The plant: an n-link planar arm as a C-source FMU (FMI 2.0 and 3.0, CS and ME).

    from plant_fmu import build_fmu
    path = build_fmu(links=2, fmi_version=2)
"""

from .build import BuildError, build_fmu
from .models.planar_arm import MAX_LINKS, MODEL_IDENTIFIER, variables

__all__ = ["BuildError", "MAX_LINKS", "MODEL_IDENTIFIER", "build_fmu", "variables"]
