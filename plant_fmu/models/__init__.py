"""The built-in plant models. Each is a package here: its C sources (the model's equations
against the FMI glue's contract, ``plant_fmu/fmi/model.h``), its one variable table
(``variables(links)``, from :mod:`plant_fmu.variables`), ``describe(links)``,
``MODEL_IDENTIFIER``, ``MAX_LINKS``, ``SOURCES`` and ``HEADERS``. A new model is a new
package, added to :data:`MODELS` (and to :data:`ARMS` if it is an arm); the glue and the
build need no change."""

from . import drives, elastic_joints, planar_arm

MODELS = {"planar_arm": planar_arm, "elastic_joints": elastic_joints, "drives": drives}
DEFAULT_MODEL = "planar_arm"
# The models that are an arm (a plant of their own: torque in, joint angles out); the
# drives are a component of a system, between the controller and an arm.
ARMS = ("planar_arm", "elastic_joints")
