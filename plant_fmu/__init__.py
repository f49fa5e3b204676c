"""The plants: built-in models as C-source FMUs (FMI 2.0 and 3.0, CS and ME) — the n-link
planar arm, and the arm with elastic joints.

    from plant_fmu import build_fmu
    path = build_fmu(links=2, fmi_version=2)                          # the rigid arm
    path = build_fmu(links=2, fmi_version=3, model="elastic_joints")
"""

from .build import BuildError, build_fmu
from .models import DEFAULT_MODEL, MODELS

__all__ = ["BuildError", "DEFAULT_MODEL", "MODELS", "build_fmu"]
