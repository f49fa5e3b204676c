"""What a run's traces need against the memory the machine has: every run's trace is kept
until the end (summary, figures), so a scenario is refused before anything is allocated
when together they would not fit."""

from __future__ import annotations

from pathlib import Path

from .schema import PipelineError


def trace_bytes(plan, steps: int) -> int:
    """What one run's trace takes (``plan``: a :class:`~cosim.assemble.RunPlan`): every
    declared signal, 8 bytes a value, steps + 1 rows."""
    return sum(s.width(plan.links) for s in plan.signals.values()) * 8 * (steps + 1)


def available_memory() -> int | None:
    """Bytes of memory available now (Linux: MemAvailable), or None if unknown."""
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def check_memory(scenario, share: float = 0.8) -> None:
    """Refuse a :class:`~cosim.assemble.Scenario` before allocating when its runs' traces
    together would need more than ``share`` of the memory available."""
    steps = scenario.steps
    needed = sum(trace_bytes(plan, steps) for plan in scenario.runs.values())
    available = available_memory()
    if available is not None and needed > share * available:
        sim = scenario.pipeline.simulation
        raise PipelineError(
            f"the traces would need {needed / 1e9:.3g} GB ({len(scenario.runs)} run(s) × "
            f"{steps + 1:,} rows of {simulation_width(scenario)} values × 8 B) but "
            f"{available / 1e9:.3g} GB of memory is available (at most {share:.0%} is used); "
            f"shorten simulation.duration ({sim.duration:g} s) or lengthen simulation.step "
            f"({sim.step:g} s)")


def simulation_width(scenario) -> int:
    plan = next(iter(scenario.runs.values()))
    return sum(s.width(plan.links) for s in plan.signals.values())
