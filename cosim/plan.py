"""``cosim run --dry-run``: everything checked and the FMU built, nothing run. Prints the
resolved plan: the plant, every run's chain of blocks, and the memory and disk it needs."""

from __future__ import annotations

from pathlib import Path

from .assemble import assemble
from .config import Pipeline
from .config.params import changed
from .memory import available_memory, trace_bytes

# Measured on the paper pipeline: recording.rrd ≈ 0.98 MB per run per simulated second at
# 1 kHz (39.2 MB for 2 × 20 s), trace_NAME.npz ≈ 0.45 of the trace's raw bytes.
RECORDING_BYTES_PER_ROW = 980.0
NPZ_SHARE = 0.45


def describe_plan(pipeline: Pipeline, out: str | Path, record: bool = True) -> str:
    scenario = assemble(pipeline)
    try:
        steps = scenario.steps
        sim = pipeline.simulation
        info = scenario.plant.info()
        lines = [f"pipeline {pipeline.name}: {len(scenario.runs)} run(s), {sim.duration:g} s "
                 f"at {1 / sim.step:g} Hz ({steps:,} steps each)",
                 f"plant: {info['file']} ({info['model_name']}, FMI {info['fmi_version']}, "
                 f"{scenario.plant.links} joints)"]
        memory = disk = 0
        for name, plan in scenario.runs.items():
            size = trace_bytes(plan, steps)
            memory += size
            disk += NPZ_SHARE * size + (RECORDING_BYTES_PER_ROW * (steps + 1) if record else 0)
            chain = " -> ".join(b.instance for b in plan.blocks)
            lines.append(f"  run {name}: {chain} -> plant ({plan.plant_input}); "
                         f"{len(plan.signals)} signals, trace {size / 1e6:.1f} MB")
        available = available_memory()
        lines.append(f"memory: {memory / 1e6:.1f} MB for the traces"
                     + (f" ({available / 1e9:.1f} GB available)" if available else ""))
        lines.append(f"disk: about {disk / 1e6:.0f} MB in {out} (traces"
                     + (", recording" if record else "") + ", figures, summary)")
        differing = changed(pipeline)
        lines.append("values that differ from the defaults (`cosim params` lists them all):")
        lines.extend(f"  {line}" for line in differing)
        lines.append("nothing was run (--dry-run)")
        return "\n".join(lines)
    finally:
        scenario.close()
