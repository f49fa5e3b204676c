"""The built-in plant models. Each is a package here: its C sources (the model's equations,
start values and get/set, against ``plant_fmu/fmi/fmu_instance.h``), its one variable table
(``variables(links)``), ``MODEL_IDENTIFIER``, ``MAX_LINKS``, ``SOURCE_DIR``, ``SOURCES`` and
``HEADERS``. A second model is a second package, added to ``MODELS``."""

from . import planar_arm

MODELS = {"planar_arm": planar_arm}
