"""A pipeline's runs: each names its chain of blocks (``blocks = [...]``, default
:func:`~cosim.blocks.default_chain`), ``"kind as name"`` for a named instance with a table
of its own."""

from __future__ import annotations

from typing import Any

from pydantic import Field, ValidationError, ValidationInfo, model_validator

from ..blocks import BLOCKS, default_chain
from ..blocks.plugins import offered_kinds
from ..schema import Section


def chain_entry(entry: str) -> tuple[str, str]:
    """(instance name, kind) of one ``blocks`` entry: ``"kind"``, or ``"kind as name"`` for
    a named instance (two of one kind in a chain). ValueError if malformed."""
    kind, _, name = (part.strip() for part in entry.partition(" as "))
    name = name or kind
    if not kind.isidentifier() or not name.isidentifier():
        raise ValueError(f"blocks: {entry!r} is not a block (\"kind\", or \"kind as name\" "
                         "for a named instance, both identifiers)")
    return name, kind


class Run(Section):
    """One run: its chain of blocks and their tables (merged over the top level's). An entry
    ``"kind as name"`` adds an instance of ``kind`` named ``name``, with its own table
    ``[runs.RUN.name]`` merged over the top-level ``[kind]`` (``instances`` holds them)."""

    blocks: list[str] = Field(default_factory=default_chain)
    instances: dict[str, dict] = {}  # named instances' tables, from [runs.RUN.NAME]

    @model_validator(mode="before")
    @classmethod
    def _gather_instances(cls, data: Any) -> Any:
        """Take each named instance's table out of the run's keys, into ``instances``."""
        if not isinstance(data, dict) or not isinstance(data.get("blocks"), list):
            return data
        instances = dict(data.get("instances") or {})
        data = dict(data)
        for entry in data["blocks"]:
            if not isinstance(entry, str):
                continue
            name, kind = chain_entry(entry)
            if name != kind and name in data:
                instances[name] = data.pop(name)
        return {**data, "instances": instances}

    @model_validator(mode="after")
    def _known_blocks(self, info: ValidationInfo) -> Run:
        # the kinds this pipeline may use: a plugin another pipeline loaded in this process
        # (a notebook, a sweep's worker) is not one of them
        plugins = (info.context or {}).get("plugins") or []
        kinds = offered_kinds(plugins)
        names: set[str] = set()
        for entry in self.blocks:
            name, kind = chain_entry(entry)
            if kind not in kinds:
                raise ValueError(f"blocks: {kind!r} is not a registered block (registered: "
                                 f"{', '.join(kinds)})")
            if name != kind:
                if name in BLOCKS or name in names:
                    raise ValueError(f"blocks: {entry!r}: the name {name!r} is taken (by a "
                                     "block kind or another instance); name it otherwise")
                self._instance_params(name, kind)  # refused here, naming the key
            names.add(name)
        unknown = sorted(set(self.instances) - names)
        if unknown:
            raise ValueError(f"instances: {', '.join(unknown)} named by no \"kind as name\" "
                             "entry of blocks")
        return self

    def _instance_params(self, name: str, kind: str) -> Section:
        try:
            return BLOCKS[kind].Params.model_validate(self.instances.get(name, {}))
        except ValidationError as exc:
            error = exc.errors()[0]
            key = ".".join(str(p) for p in error["loc"])
            raise ValueError(f"{name}.{key}: {error['msg']} (got {error.get('input')!r})"
                             ) from None

    def chain(self) -> list[tuple[str, str]]:
        """(instance name, kind) of every block in order."""
        return [chain_entry(entry) for entry in self.blocks]

    def block_params(self, name: str) -> Section:
        """The table of the block named ``name`` (its kind, or a named instance's)."""
        kinds = dict(self.chain())
        if name in kinds and kinds[name] != name:
            return self._instance_params(name, kinds[name])
        return getattr(self, name)
