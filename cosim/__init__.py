"""cosim: co-simulate a robot-arm FMU with a safe adaptive output-feedback controller."""

__version__ = "0.1.0"
