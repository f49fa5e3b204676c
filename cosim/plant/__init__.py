"""The plant: an FMU behind one interface, whatever its FMI version or exporter.

- :mod:`.ports`: the one table of the plant's ports (``tau`` in; ``q``, optional ``qdot``,
  ``M``, ``theta`` out), and the :class:`~.ports.Plant` protocol;
- :mod:`.mapping`: does an FMU fit those ports, and safe extraction;
- :mod:`.lifecycle`: one FMI life cycle (instantiate, initialise, reset, free) per version,
  shared by the co-simulation adapter, linearisation and the tests;
- :mod:`.fmu`: the co-simulation adapter the master steps;
- :mod:`.inspection`, :mod:`.linearization`: ``cosim inspect`` and ``linearize``.
"""

from .ports import OUTPUT_PORTS, PLANT_INPUT, PLANT_INPUT_ENTITY, PLANT_OUTPUTS, PORTS, Plant

__all__ = ["OUTPUT_PORTS", "PLANT_INPUT", "PLANT_INPUT_ENTITY", "PLANT_OUTPUTS", "PORTS",
           "Plant"]
