"""What every block is, and the registry pipelines find blocks in.

A block declares:

- ``kind``: its name in pipelines (``blocks = [...]``) and the name of its table;
- ``Params``: a :class:`~cosim.schema.Section` whose fields, defaults, units and
  documentation are the block's parameters *and* its pipeline schema (one source);
- ``inputs``: the signals it reads at row k (``delayed``: only at rows before k, so their
  producer may come later in the chain: the torque fed back to the observer);
- ``outputs``: the signals it writes, each a :class:`~cosim.signals.Signal`;
- ``publishes`` / ``requires``: named constants (a model, a gain) it offers to the blocks
  after it, and those it needs from the blocks before it. Blocks know each other only
  through signals and these constants, never through another block's table.

A block that reads and writes the same signal *filters* it: it sees the value produced
before it, and the value it writes replaces it downstream (the earlier value stays in the
trace as ``<signal>_<producer kind>``).

Checking: ``check(published)``, as the run is assembled, refuses parameters that cannot
work with the constants the blocks before publish (the step against a controller's gains).

Stepping: ``reset(ports)`` binds the trace arrays and sets the initial state;
``step(k)`` computes row k and returns False if an output is not finite. A block whose
work is a numba kernel ``kernel(k, args) -> bool`` (``args``: a NamedTuple set by reset,
built by :meth:`Block.bind` from what its fields declare, :mod:`cosim.blocks.binding`)
gets ``step`` for free, and the master can fuse it with the
others into one compiled loop.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from ..declared import Safety, Uncertainty
from ..schema import Section, per_joint_keys
from ..signals import Signal, Trace
from .binding import Record, bind, kernel_args

__all__ = ["BLOCKS", "Block", "BlockContext", "Ports", "default_chain", "kernel_args",
           "register_block", "set_default_chain"]


@dataclass(frozen=True)
class BlockContext:
    """What a block may know of the scenario when it is built: the joint count, the master
    step (s), the run's name, the plant outputs available (ports of cosim.plant.ports the
    plant maps: ``q``, ``qdot``, ``M``, …), the pipeline's declared safe set (``[safety]``)
    and uncertainty (``[uncertainty]``), and the plant's file name (for messages). A block
    whose parameters need what the plant lacks refuses it in its constructor with a
    :class:`~cosim.schema.PipelineError` naming the key."""

    links: int
    dt: float
    run: str
    plant_outputs: frozenset[str]
    safety: Safety = field(default_factory=Safety)
    uncertainty: Uncertainty = field(default_factory=Uncertainty)
    plant_file: str = "the plant"
    duration: float = 20.0


@dataclass
class Ports:
    """A block's view of the trace: its inputs and outputs by signal name."""

    inputs: Mapping[str, np.ndarray]
    outputs: Mapping[str, np.ndarray]
    trace: Trace  # for whole-run blocks (the reference writes all rows in reset)
    # what ``requires`` names, each of the type its publisher declares (``PUBLISHES``)
    constants: Mapping[str, object] = field(default_factory=dict)


class Block:
    kind: ClassVar[str]
    Params: ClassVar[type[Section]]
    kernel: ClassVar[Callable[..., bool] | None] = None
    # Parameters given per joint (a list must have one entry per joint; a scalar serves all):
    # those Params declares cosim.schema.PerJoint, by key, set as the class is made.
    per_joint: ClassVar[tuple[str, ...]] = ()
    # The constants its instances publish, each with its type: the wiring checks every
    # published value against it, and names the publishers in its messages.
    PUBLISHES: ClassVar[Mapping[str, type | tuple[type, ...]]] = {}
    # Views it adds to the Rerun layout of a run that holds it: (entity under the block's
    # instance name, title); the layout knows no block by name.
    views: ClassVar[tuple[tuple[str, str], ...]] = ()

    def __init__(self, params: Section, context: BlockContext):
        self.params = params
        self.context = context
        self.instance = self.kind  # its name in the chain (another for "kind as name")
        self.name = self.kind.replace("_", " ")  # in messages
        self.inputs: tuple[str, ...] = ()
        self.delayed: tuple[str, ...] = ()
        self.outputs: dict[str, Signal] = {}
        self.publishes: dict[str, object] = {}  # constants for the blocks after this one
        self.requires: tuple[str, ...] = ()  # constants from the blocks before this one
        self.args: tuple | None = None  # the kernel's arguments, set by reset

    def __init_subclass__(cls, **kwargs) -> None:
        super().__init_subclass__(**kwargs)
        # A numba dispatcher binds like a method; a kernel is a plain function of (k, args).
        kernel = cls.__dict__.get("kernel")
        if kernel is not None and not isinstance(kernel, staticmethod):
            cls.kernel = staticmethod(kernel)
        params = cls.__dict__.get("Params")
        if isinstance(params, type) and issubclass(params, Section):
            cls.per_joint = tuple(dict.fromkeys((*per_joint_keys(params),
                                                 *cls.__dict__.get("per_joint", ()))))

    def reset(self, ports: Ports) -> None:
        raise NotImplementedError

    def bind(self, record: type[Record], ports: Ports, sizes: dict[str, int] | None = None,
             **computed: object) -> Record:
        """The kernel's record, its declared fields bound from this block's parameters,
        context and ports (:mod:`cosim.blocks.binding`), the others from ``computed``;
        ``sizes`` names the sizes its scratch's shapes use beyond ``n``."""
        return bind(record, self, ports, sizes, **computed)

    def step(self, k: int) -> bool:
        return True if self.kernel is None else self.kernel(k, self.args)

    def check(self, published: Mapping[str, object]) -> None:
        """Refuse, with a :class:`~cosim.schema.PipelineError` naming the key, parameters
        that cannot work with what the blocks before this one publish (``published``: every
        constant so far, by name; a controller's gains against the model's inertia along
        the reference, say). Called as the run is assembled, so `--dry-run` refuses them
        too. Nothing by default."""

    def warm_parts(self) -> list[tuple[object, tuple]]:
        """Compiled callees of the kernel that a warm-up compiles as jobs of their own, each
        with the argument types the kernel calls it with: (dispatcher, signature), after
        reset. A large callee compiled in another process while the kernel's other callees
        compile in this one shortens a cold warm-up; the kernel loads it from the cache
        where it is done first (else compiles it too: the warm-up is as long as without).
        None by default (an empty list)."""
        return []

    def describe(self) -> dict:
        """What summary.json records of this block beyond its parameters (none by default)."""
        return {}

    def headline(self) -> str | None:
        """A line a run prints as it starts, for a choice the user should see (none by
        default)."""
        return None


BLOCKS: dict[str, type[Block]] = {}


# A pipeline's own top-level keys (cosim.config.pipeline.Pipeline's fields, runs and extends):
# no block kind may take one, its table would be the pipeline's.
PIPELINE_TABLES = ("name", "description", "plugins", "simulation", "robot", "plant",
                   "safety", "uncertainty", "runs", "extends")


def register_block(cls: type[Block]) -> type[Block]:
    """Class decorator: make ``cls`` available to pipelines as ``cls.kind``."""
    kind = getattr(cls, "kind", None)
    if not isinstance(kind, str) or not kind.isidentifier():
        raise TypeError(f"{cls.__name__}.kind must be an identifier (got {kind!r})")
    if not (isinstance(getattr(cls, "Params", None), type) and issubclass(cls.Params, Section)):
        raise TypeError(f"{cls.__name__}.Params must be a cosim.schema.Section")
    if kind in PIPELINE_TABLES:
        raise ValueError(f"{cls.__name__}.kind = {kind!r} is the name of a pipeline's own key "
                         f"({', '.join(PIPELINE_TABLES)}); a block's table would collide with "
                         "it: choose another kind")
    if kind in BLOCKS and BLOCKS[kind] is not cls:
        raise ValueError(f"a block of kind {kind!r} is registered already "
                         f"({BLOCKS[kind].__module__}.{BLOCKS[kind].__name__})")
    BLOCKS[kind] = cls
    return cls


# The chain a run steps when its pipeline names none, in the order data flows: set by the
# package that provides a whole controller (the paper's, cosim.paper).
_DEFAULT_CHAIN: list[str] = []


def set_default_chain(kinds: list[str] | tuple[str, ...]) -> None:
    """Make ``kinds`` (registered block kinds) the chain of a run whose pipeline names none."""
    missing = [kind for kind in kinds if kind not in BLOCKS]
    if missing:
        raise ValueError(f"default chain: no block of kind {', '.join(map(repr, missing))} is "
                         "registered")
    _DEFAULT_CHAIN[:] = kinds


def default_chain() -> list[str]:
    """The chain of a run whose pipeline names none (empty: every run must name one)."""
    return list(_DEFAULT_CHAIN)
