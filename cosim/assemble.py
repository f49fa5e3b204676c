"""Assembly: a pipeline becomes a :class:`Scenario` (the plant, and per run its blocks in
order, wired signal by signal), checked before anything runs or is written.

Wiring is checked as python-control's ``interconnect`` does: every input a block reads must
be produced before it (by the plant or an earlier block; a *delayed* input by any block),
every signal has one producer (a block that reads and writes a signal filters it), the
plant's torque input must be produced, and every output must be read by something or
recorded. The evaluation reads what it finds and does not constrain the chain. Each problem
is one :class:`PipelineError` naming the run, the block and the signal.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from . import interface as io
from .blocks import BLOCKS, Block, BlockContext, Ports
from .blocks.plugins import offered_kinds
from .config import Pipeline, PipelineError
from .declared import Uncertainty
from .evaluate import Declaration, Evaluator, SafeSet, evaluated_signals
from .evaluate.parts import select
from .memory import check_memory
from .plant import PLANT_INPUT, PLANT_INPUT_ENTITY, PLANT_OUTPUTS, Plant
from .plant.fmu import Fmu, FmuError
from .plant.ports import traced_outputs
from .plant_source import open_plant
from .signals import Signal, Trace, trace_name_clash
from .system.plant import SystemPlant


@dataclass
class RunPlan:
    """One run, assembled: blocks in order, the trace's signals and where each block's
    ports are in it."""

    name: str
    blocks: list[Block]
    signals: dict[str, Signal]  # trace key -> declaration, plant outputs first
    inputs: list[dict[str, str]]  # per block: port -> trace key
    outputs: list[dict[str, str]]
    plant_input: str  # trace key of the torque the plant is given
    safe: SafeSet
    links: int
    dt: float
    params: object  # the run's validated tables (pipeline.runs[name])
    constants: list[dict] = field(default_factory=list)  # per block: what it requires
    uncertainty: Uncertainty = field(default_factory=Uncertainty)
    # The plant outputs the plant maps; the others stay NaN in the trace and count as absent.
    plant_outputs: frozenset[str] = frozenset(PLANT_OUTPUTS)

    def new_trace(self, steps: int) -> Trace:
        return Trace(self.signals, self.links, steps, self.dt)

    def reset(self, trace: Trace) -> None:
        """Bind every block to ``trace`` and set its initial state, in chain order."""
        constants = self.constants or [{} for _ in self.blocks]
        for block, ins, outs, const in zip(self.blocks, self.inputs, self.outputs, constants,
                                           strict=True):
            block.reset(Ports({port: trace[key] for port, key in ins.items()},
                              {port: trace[key] for port, key in outs.items()}, trace, const))

    def published(self) -> dict:
        """Every constant the run's blocks publish (a later block's replaces an earlier's)."""
        out: dict = {}
        for block in self.blocks:
            out.update(block.publishes)
        return out

    def evaluator(self, trace: Trace, facts: dict | None = None) -> Evaluator:
        """The run's evaluation; ``facts``: what the framework gives every evaluator beside
        the blocks' constants (:mod:`cosim.interface`: the plant's parameters, the declared
        uncertainty)."""
        return Evaluator(trace, self.safe, {**(facts or {}), **self.published()},
                         self._unmapped())

    def _unmapped(self) -> frozenset[str]:
        return frozenset(PLANT_OUTPUTS) - self.plant_outputs

    def declarations(self) -> list[Declaration]:
        """The check families the run's evaluators declare (those its signals and published
        constants allow), in their order."""
        chosen, _ = select(self.signals, self.published(), self._unmapped())
        return [d for cls in chosen for d in cls.declarations]

    def entities(self) -> dict[str, tuple[str, str]]:
        """Recording entity under ``/<run>/`` -> (trace key, series-name stem), from the
        declarations; the torque applied to the plant also as ``plant/tau``."""
        out = {}
        for key, signal in self.signals.items():
            if signal.entity is not None:
                out[signal.entity] = (key, signal.label or key)
        out[PLANT_INPUT_ENTITY] = (self.plant_input, PLANT_INPUT)
        return out

    def torque_before_filter(self) -> tuple[str, str] | None:
        """(trace key of the plant's torque as the last block that changed it read it, that
        block's kind): what a filter corrected. None when one block alone produced it."""
        for block, ins, outs in zip(reversed(self.blocks), reversed(self.inputs),
                                    reversed(self.outputs), strict=True):
            if PLANT_INPUT in outs:
                return (ins[PLANT_INPUT], block.instance) if PLANT_INPUT in ins else None
        return None

    def views(self) -> list[tuple[str, str]]:
        """The views the run's blocks add to its Rerun layout: (entity under ``/<run>/``,
        title), each under its block's instance name."""
        return [(f"{block.instance}/{entity}", title)
                for block in self.blocks for entity, title in block.views]

    def block(self, kind: str) -> Block | None:
        return next((b for b in self.blocks if b.kind == kind), None)

    def publisher(self, constant: str) -> Block | None:
        """The last block that publishes ``constant`` (the one later blocks see)."""
        return next((b for b in reversed(self.blocks) if constant in b.publishes), None)


@dataclass
class Scenario:
    """The pipeline, its plant (opened and started once, to check it), and every run."""

    pipeline: Pipeline
    plant: Fmu | SystemPlant
    runs: dict[str, RunPlan] = field(default_factory=dict)
    owns_plant: bool = True  # False: the caller's plant, re-used across scenarios

    @property
    def steps(self) -> int:
        return self.pipeline.simulation.steps

    def close(self) -> None:
        if self.owns_plant:
            self.plant.close()


def assemble(pipeline: Pipeline, plant: Fmu | SystemPlant | None = None) -> Scenario:
    """Open and start the plant (refusing bad parameters), then assemble and check every
    run, and that their traces fit in memory. Nothing is written; the caller closes the
    scenario. ``plant``: an open plant of the same FMU and mapping to re-use (a sweep's
    worker), given this pipeline's parameters; it stays open."""
    owns = plant is None
    try:
        if owns:
            plant = open_plant(pipeline)
        else:
            plant.set_parameters(dict(pipeline.plant.parameters))
    except FmuError as exc:
        raise PipelineError(str(exc)) from None
    try:
        plant.start(0.0)
        scenario = Scenario(pipeline, plant, owns_plant=owns)
        for name in pipeline.runs:
            scenario.runs[name] = assemble_run(pipeline, name, plant)
        check_memory(scenario)
        return scenario
    except (PipelineError, FmuError) as exc:
        if owns:
            plant.close()
        raise PipelineError(str(exc)) from None


def plant_outputs(plant: Plant) -> frozenset[str]:
    """The plant outputs a block may read: the output ports the plant maps (q always)."""
    return frozenset(plant.mapped) & frozenset(PLANT_OUTPUTS)


def assemble_run(pipeline: Pipeline, name: str, plant) -> RunPlan:
    """One run's blocks, built from its tables and wired. ``plant`` needs ``links`` and
    ``mapped`` (a :class:`~cosim.plant.Plant`), and a ``path`` for messages, only."""
    run = pipeline.runs[name]
    links, dt = plant.links, pipeline.simulation.step
    file = getattr(getattr(plant, "path", None), "name", "the plant")
    context = BlockContext(links, dt, name, plant_outputs(plant), pipeline.safety,
                           pipeline.uncertainty, file, pipeline.simulation.duration)
    check_sizes(run, name, plant)
    for key in ("viscous_friction", "coulomb_friction"):  # per joint, or one for all
        value = getattr(pipeline.uncertainty, key)
        if isinstance(value, list) and len(value) != links:
            raise PipelineError(f"uncertainty.{key} has {len(value)} entries; the plant "
                                f"({file}) has {links} joint{'s' * (links != 1)}")
    blocks = []
    for instance, kind in run.chain():
        block = BLOCKS[kind](run.block_params(instance), context)
        if instance != kind:  # a named instance: its messages, kept signals and entities
            block.instance, block.name = instance, instance.replace("_", " ")
        blocks.append(block)
    kinds = offered_kinds(pipeline.plugins)
    signals, inputs, outputs, plant_input = wire(blocks, context, name, plant, kinds)
    constants = wire_constants(blocks, name, kinds)
    published: dict = {}
    for block in blocks:
        block.check(published)
        published.update(block.publishes)
    return RunPlan(name, blocks, signals, inputs, outputs, plant_input,
                   safe_set(pipeline), links, dt, run, constants, pipeline.uncertainty,
                   context.plant_outputs)


def wire_constants(blocks: list[Block], run: str,
                   kinds: dict[str, type[Block]] | None = None) -> list[dict]:
    """Per block, the constants it ``requires``, each from the nearest block before it that
    ``publishes`` it; :class:`PipelineError` naming the run, block and constant (and which
    of ``kinds``, default every registered block, publish it) if none."""
    published: dict = {}
    out = []
    for block in blocks:
        needed = {}
        for name in block.requires:
            if name not in published:
                makers = [kind for kind, cls in (kinds or BLOCKS).items()
                          if name in _published_by(cls)]
                hint = f"published by: {', '.join(makers)}" if makers else "no block publishes it"
                raise PipelineError(f"run '{run}': the {block.instance} block needs the constant "
                                    f"'{name}', which no block before it publishes ({hint})")
            needed[name] = published[name]
        out.append(needed)
        declared = dict(getattr(block, "PUBLISHES", {}))
        for name, value in block.publishes.items():
            if name not in declared or not isinstance(value, declared[name]):
                what = (f"of type {type(value).__name__}, declared "
                        f"{getattr(declared[name], '__name__', declared[name])}"
                        if name in declared else "not declared in its PUBLISHES")
                raise PipelineError(f"run '{run}': the {block.instance} block publishes "
                                    f"'{name}' {what}")
        published.update(block.publishes)
    return out


def _published_by(cls: type[Block]) -> tuple[str, ...]:
    return tuple(getattr(cls, "PUBLISHES", {}))


def wire(blocks: list[Block], context: BlockContext, run: str, plant,
         kinds: dict[str, type[Block]] | None = None
         ) -> tuple[dict[str, Signal], list[dict[str, str]], list[dict[str, str]], str]:
    """Resolve every port to a trace key; :class:`PipelineError` on the first problem (its
    hint names which of ``kinds``, default every registered block, would produce a port)."""
    file = getattr(getattr(plant, "path", None), "name", "the plant")
    where = f"run '{run}'"
    signals: dict[str, Signal] = traced_outputs(context.plant_outputs)  # NaN where not mapped
    signals.update(getattr(plant, "signals", {}))  # a system's components' own, recorded
    current = {s: s for s in context.plant_outputs}  # signal -> trace key of its latest value
    producer = {s: "plant" for s in context.plant_outputs}
    inputs: list[dict[str, str]] = []
    outputs: list[dict[str, str]] = []
    read: set[str] = set()
    for block in blocks:
        ins = {}
        for port in block.inputs:
            if port not in current:
                hint = (f"{file} does not map it (plant.variables.{port})" if port in PLANT_OUTPUTS
                        else _producers_hint(port, blocks, kinds or BLOCKS))
                raise PipelineError(f"{where}: the {block.instance} block reads '{port}', which "
                                    f"nothing before it produces ({hint})")
            ins[port] = current[port]
        outs = {}
        for port, signal in block.outputs.items():
            clash = trace_name_clash(port)
            if clash:
                raise PipelineError(f"{where}: the {block.instance} block writes '{port}', "
                                    f"{clash}; rename that output")
            if block.instance != block.kind and signal.entity is not None:
                # a named instance records under its own name (two of one kind apart)
                head, _, rest = signal.entity.partition("/")
                if head == block.kind:
                    signal = replace(signal, entity=f"{block.instance}/{rest}")
            if port in current:
                if port not in block.inputs:
                    raise PipelineError(
                        f"{where}: '{port}' is produced twice, by the {producer[port]} and "
                        f"the {block.instance} block; a block that changes a signal must also "
                        "read it (a filter)")
                if producer[port] == "plant":
                    raise PipelineError(f"{where}: the {block.instance} block writes '{port}', "
                                        f"a plant output; blocks may only read it")
                # A filter: the value before it is kept under its producer's name.
                kept = f"{port}_{producer[port]}"
                signals[kept] = signals.pop(current[port])
                for bindings in (*inputs, *outputs, ins):
                    for p, key in bindings.items():
                        if key == current[port]:
                            bindings[p] = kept
            signals[port] = signal
            current[port] = port
            producer[port] = block.instance
            outs[port] = port
        read.update(ins.values())
        inputs.append(ins)
        outputs.append(outs)
    for block, ins in zip(blocks, inputs, strict=True):  # delayed: the final value
        for port in block.delayed:
            if port not in current:
                raise PipelineError(f"{where}: the {block.instance} block reads '{port}' of the "
                                    f"previous step, which no block produces "
                                    f"({_producers_hint(port, blocks, kinds or BLOCKS)})")
            ins[port] = current[port]
            read.add(current[port])
    if PLANT_INPUT not in current or producer[PLANT_INPUT] == "plant":
        raise PipelineError(f"{where}: no block produces '{PLANT_INPUT}', the plant's torque "
                            f"input (chain: {', '.join(b.instance for b in blocks)})")
    read.add(current[PLANT_INPUT])
    _check_read_or_recorded(signals, read, producer, where)
    return signals, inputs, outputs, current[PLANT_INPUT]


def _check_read_or_recorded(signals: dict[str, Signal], read: set[str],
                            producer: dict[str, str], where: str) -> None:
    """Every block's output read, recorded (one entity each) or evaluated."""
    evaluated = evaluated_signals()
    entities: dict[str, str] = {}
    for key, signal in signals.items():
        owner = "plant" if key in PLANT_OUTPUTS else producer.get(key, key)
        if signal.entity is None and key not in read and owner != "plant" \
                and key not in evaluated and not signal.kept:
            raise PipelineError(f"{where}: the {owner} block's output '{key}' is neither read "
                                "nor recorded (give it an entity, or drop it)")
        if signal.entity is not None:
            if signal.entity in entities:
                raise PipelineError(f"{where}: '{key}' and '{entities[signal.entity]}' are "
                                    f"both recorded as '{signal.entity}'")
            entities[signal.entity] = key


def _producers_hint(port: str, chain: list[Block], kinds: dict[str, type[Block]]) -> str:
    """Which of ``kinds`` would produce ``port``, for the message."""
    context = chain[0].context if chain else None
    makers = []
    for kind, cls in kinds.items():
        try:
            block = cls(cls.Params(), context)
        except Exception:  # a block that cannot be built with its defaults here
            continue
        if port in block.outputs:
            makers.append(kind)
    return (f"produced by: {', '.join(makers)}" if makers
            else "no registered block produces it")


def check_sizes(run, name: str, plant) -> None:
    """Every block parameter given per joint (its kind's ``per_joint``) must have the
    plant's n entries; else one :class:`PipelineError` naming the key. What a block needs of
    the plant beyond that, it checks itself when built (:class:`BlockContext`)."""
    n = plant.links
    file = getattr(getattr(plant, "path", None), "name", "the plant")
    joints = f"the plant ({file}) has {n} joint{'s' * (n != 1)}"
    sized = {}
    for instance, kind in run.chain():
        values = run.block_params(instance).model_dump(by_alias=True)
        for key in BLOCKS[kind].per_joint:
            if isinstance(values.get(key), list):
                sized[f"{instance}.{key}"] = values[key]
    for key, value in sized.items():
        if len(value) != n:
            raise PipelineError(f"{key} (run '{name}') has {len(value)} entries; {joints}")


def safe_set(pipeline: Pipeline) -> SafeSet:
    """The safe sets' bounds the run is evaluated against: the pipeline's [safety]."""
    return pipeline.safety


def link_lengths(plant_info: dict, plan: RunPlan) -> np.ndarray:
    """Link lengths for drawing the arm: the FMU's ``l[i]`` parameters, else the nominal
    chain a block of the run publishes, else 1 m each."""
    params = plant_info["parameters"]
    names = [f"l[{i}]" for i in range(1, plan.links + 1)]
    if all(n in params for n in names):
        return np.array([params[n] for n in names])
    chain = plan.published().get(io.PLANT_MODEL)
    return np.array(chain.l, float) if chain is not None else np.ones(plan.links)
