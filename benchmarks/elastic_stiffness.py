"""What holds of the paper's controllers, the safety filter and PD control on the arm with
elastic joints as the joints soften (pipelines/elastic_joints.toml): the table of docs/plants.md.

    .venv/bin/python benchmarks/elastic_stiffness.py [--duration 20]

A row per joint stiffness k (both joints, N·m/rad; motor inertia J = 0.05 kg·m² and damping
d = 10 N·m·s/rad as in the pipeline); every controller keeps the nominal rigid model. Cells
as in benchmarks/robustness.py: the joint-1 sets left (P position, V true velocity, E error,
Ė error rate), the peak torque (N·m) and, from 2 up, the torque reversals per second.
SI units, radians.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from robustness import table

PIPELINE = Path(__file__).resolve().parent.parent / "pipelines" / "elastic_joints.toml"
STIFFNESS = (1e6, 1e5, 3e4, 1e4, 3e3)  # N·m/rad


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=20.0, help="simulated seconds")
    args = parser.parse_args()
    conditions = {f"k = {k:g}": [f'plant.parameters."k[{i}]"={k}' for i in (1, 2)]
                  for k in STIFFNESS}
    return table(PIPELINE, conditions, args.duration, "stiffness (N·m/rad)")


if __name__ == "__main__":
    sys.exit(main())
