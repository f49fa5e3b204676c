"""Running an assembled run: the fixed-step master and its fused compiled loop."""

from .master import ENGINES, Diverged, PlantFailed, simulate

__all__ = ["ENGINES", "Diverged", "PlantFailed", "simulate"]
