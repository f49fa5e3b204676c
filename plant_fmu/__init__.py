"""The plants: built-in models as C-source FMUs (FMI 2.0 and 3.0, CS and ME) — the n-link
planar arm, the arm with elastic joints, the spatial chain of a robot's URDF, and the
joints' drives (a component of a system of FMUs).

    from plant_fmu import build_fmu, build_urdf_fmu
    path = build_fmu(links=2, fmi_version=2)                          # the rigid arm
    path = build_fmu(links=2, fmi_version=3, model="elastic_joints")
    path = build_urdf_fmu("panda.urdf", tip="panda_hand")             # a real arm
    path = build_fmu(links=2, model="drives")   # the joints' drives, a system's component
"""

from .build import BuildError, build_fmu, build_urdf_fmu
from .models import ARMS, DEFAULT_MODEL, MODELS
from .urdf import Chain, UrdfError, read_urdf

__all__ = ["ARMS", "BuildError", "Chain", "DEFAULT_MODEL", "MODELS", "UrdfError", "build_fmu",
           "build_urdf_fmu", "read_urdf"]
