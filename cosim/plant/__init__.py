"""The plant: an FMU behind one interface, whatever its FMI version or exporter.

- :mod:`.mapping`: does an FMU fit our interface (``tau`` in; ``q``, optional ``qdot`` and
  ``M`` out), and safe extraction;
- :mod:`.lifecycle`: one FMI life cycle (instantiate, initialise, reset, free) per version,
  shared by the co-simulation adapter, linearisation and the tests;
- :mod:`.fmu`: the co-simulation adapter the master steps;
- :mod:`.inspection`, :mod:`.linearization`: ``cosim inspect`` and ``linearize``.

The signals the plant contributes to every trace are declared here.
"""

from ..signals import Signal

# Plant outputs, ground truth from the FMU. An output the FMU does not map stays NaN in the
# trace, and no block may read it.
PLANT_OUTPUTS = {
    "q": Signal("n", "rad", "joint angles q (plant)", "plant/q"),
    "qdot": Signal("n", "rad/s", "joint velocities q̇ (plant)", "plant/qdot"),
    # n² series per run add little to the review; the trace files keep M.
    "M": Signal("nn", "kg·m²", "inertia matrix M(q) (plant)"),
}
# The plant's input: the torque the last block in the chain produces under this name.
PLANT_INPUT = "tau"
PLANT_INPUT_ENTITY = "plant/tau"
