"""A plant that is a system of FMUs (docs/systems.md): several FMUs connected as an SSP 1.0
file or a pipeline's ``[plant.system]`` describes them, run as one plant.

- :mod:`.structure`: the system as cosim holds it (components, connectors, connections);
- :mod:`.ssp`: SSP 1.0 archives read into one and written from one;
- :mod:`.wiring`: the system checked against its components' FMUs;
- :mod:`.order`: the order values pass on at each step (direct feedthrough, loops);
- :mod:`.plant`: the system as the master steps it, behind the plant's interface;
- :mod:`.export`, :mod:`.inspection`: ``cosim export-ssp`` and ``cosim inspect X.ssp``.
"""
