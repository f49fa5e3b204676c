"""The declared interface: the signals and constants through which the framework evaluates
a run's tracking and safe sets, whatever blocks produce them. SI units, radians.

A reference publishes the desired trajectory and the safe sets' centres; a controller that
is to be evaluated like the paper's publishes its tracking error, the error's rate and where
the velocity in that rate comes from. The framework reads a run only through these names
and the plant's ports (:mod:`cosim.plant.ports`); every other signal is its block's own.
"""

from __future__ import annotations

# Signals (one row per step, one column per joint).
DESIRED_POSITION = "q_d"  # q_d, the reference's position, rad
DESIRED_VELOCITY = "qdot_d"  # q̇_d, rad/s
SAFE_CENTRE = "q_s"  # q_s, the centre of the position set, rad
SAFE_VELOCITY_CENTRE = "qdot_s"  # q̇_s, the centre of the velocity set, rad/s
TRACKING_ERROR = "e"  # e = q_d − q, rad
# ė = q̇_d − v, v the velocity the controller fed back (the true q̇ or an estimate), rad/s
TRACKING_ERROR_RATE = "edot"

# Constants (published once per run).
# Where the controller's v comes from: "plant" (the true q̇) or the name of an estimate
# ("observer", "finite_difference"); a controller that does not say is taken to estimate.
VELOCITY_SOURCE = "velocity_source"
TRUE_VELOCITY = "plant"  # the value of VELOCITY_SOURCE for a full-state controller


# The nominal model of the plant a block publishes (its ``describe()`` is the run's
# ``inertia_model`` in summary.json; its link lengths draw the arm).
PLANT_MODEL = "nominal_chain"

# What the framework gives every evaluator besides the blocks' constants.
PLANT_PARAMETERS = "plant_parameters"  # the plant FMU's parameters, name -> value (SI)
# A system of FMUs as the plant (None for one FMU): the component the joint angles come from
# ("arm"), the trace key of its torque input ("arm_torque"), and per component its model and
# parameters ("components"); cosim.system.plant.SystemPlant.info's "system"
PLANT_SYSTEM = "plant_system"
UNCERTAINTY = "uncertainty"  # the pipeline's declared [uncertainty]

# Series (per row, from an evaluator): the condition on its barrier functions, ≥ 0 where it
# holds; recorded at ``barrier_condition`` with its failing rows marked, drawn beside them.
BARRIER_CONDITION = "condition"
SERIES = (BARRIER_CONDITION,)

# The names above that blocks produce (the framework reads them, blocks write them).
NAMES = (DESIRED_POSITION, DESIRED_VELOCITY, SAFE_CENTRE, SAFE_VELOCITY_CENTRE,
         TRACKING_ERROR, TRACKING_ERROR_RATE, VELOCITY_SOURCE, PLANT_MODEL)
