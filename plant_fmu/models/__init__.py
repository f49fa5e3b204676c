"""The built-in plant models. Each is a package here: its C sources (the model's equations
against the FMI glue's contract, ``plant_fmu/fmi/model.h``), its one variable table
(``variables(links)``, from :mod:`plant_fmu.variables`), ``describe(links)``,
``MODEL_IDENTIFIER``, ``MAX_LINKS``, ``SOURCES`` and ``HEADERS``. A new model is a new
package, added to :data:`MODELS`; the glue and the build need no change."""

from . import elastic_joints, planar_arm

MODELS = {"planar_arm": planar_arm, "elastic_joints": elastic_joints}
DEFAULT_MODEL = "planar_arm"
