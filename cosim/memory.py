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
    return (limited_memory() or (None, ""))[0] or _meminfo()


def limited_memory() -> tuple[int, str] | None:
    """The tightest of the limits on this process that MemAvailable does not show, as
    (bytes left, which limit): the address space (``ulimit -v``), the cgroup (a
    container's memory limit); None when neither applies or both leave more."""
    limits = [left for left in (_address_space_left(), _cgroup_left()) if left is not None]
    machine = _meminfo()
    tightest = min(limits, default=None)
    if tightest is None or (machine is not None and tightest[0] >= machine):
        return None
    return tightest


def _meminfo() -> int | None:
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def _address_space_left() -> tuple[int, str] | None:
    import resource

    soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    if soft == resource.RLIM_INFINITY:
        return None
    try:
        status = Path("/proc/self/status").read_text()
        used = next(int(line.split()[1]) * 1024 for line in status.splitlines()
                    if line.startswith("VmSize:"))
    except (OSError, ValueError, StopIteration):
        used = 0
    return max(0, soft - used), "the address-space limit, ulimit -v"


def _cgroup_left() -> tuple[int, str] | None:
    root = Path("/sys/fs/cgroup")
    try:
        limit = (root / "memory.max").read_text().strip()
        if limit == "max":
            return None
        used = int((root / "memory.current").read_text())
        return max(0, int(limit) - used), "the container's memory limit, memory.max"
    except (OSError, ValueError):
        return None


def check_memory(scenario, share: float = 0.8) -> None:
    """Refuse a :class:`~cosim.assemble.Scenario` before allocating when its runs' traces
    together would need more than ``share`` of the memory available."""
    steps = scenario.steps
    needed = sum(trace_bytes(plan, steps) for plan in scenario.runs.values())
    limited = limited_memory()
    available = limited[0] if limited else available_memory()
    if available is not None and needed > share * available:
        sim = scenario.pipeline.simulation
        which = f" under {limited[1]}" if limited else ""
        rows = steps + 1  # digit by digit while a reader can count them (1e300 s: 301 digits)
        shown = f"{rows:,}" if rows < 10**15 else f"{rows:.3g}"
        raise PipelineError(
            f"the traces would need {needed / 1e9:.3g} GB ({len(scenario.runs)} run(s) × "
            f"{shown} rows of {simulation_width(scenario)} values × 8 B) but "
            f"{available / 1e9:.3g} GB of memory is available{which} (at most {share:.0%} is "
            "used); "
            f"shorten simulation.duration ({sim.duration:g} s) or lengthen simulation.step "
            f"({sim.step:g} s)")


def simulation_width(scenario) -> int:
    plan = next(iter(scenario.runs.values()))
    return sum(s.width(plan.links) for s in plan.signals.values())
