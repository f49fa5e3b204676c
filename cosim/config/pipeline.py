"""The pipeline model, assembled from the block registry: every registered block's
``Params`` is a table (``[controller]``, ``[observer]``, …) at the top level and in each run,
and each run's tables (``[runs.NAME.controller]`` …) are merged over the top level's.
SI units, radians.
"""

from __future__ import annotations

from typing import Any

from pydantic import PrivateAttr, create_model, model_validator

from ..blocks import BLOCKS
from ..blocks.plugins import load_entry_points
from ..declared import Safety, Uncertainty, safety_section
from ..schema import Section
from .runs import Run, chain_entry
from .sections import Plant, Robot, Simulation, check_name, robot_defaults


class Pipeline(Section):
    """The fixed tables; the block tables are added from the registry by
    :func:`pipeline_model`."""

    # the pipeline's name, naming its run folder (runs/NAME) and its recording, a name
    name: str = "pipeline"
    # what the pipeline is for, kept in summary.json and the recording, free text
    description: str = ""
    # modules of the user's own blocks and evaluators, imported (their code run) before the
    # pipeline is validated: .py files relative to the pipeline file naming them, or
    # importable module names, paths or names
    plugins: list[str] = []
    simulation: Simulation = Simulation()
    # the robot the pipeline is about, named once (its URDF, base, tip and held joints): the
    # plant, the nominal model and the safe sets where they are not given (a path, or a
    # table: file, base, tip, fixed)
    robot: Robot | None = None
    plant: Plant = Plant()
    safety: Safety = Safety()
    uncertainty: Uncertainty = Uncertainty()
    # Then a table per registered block, and last ``runs: dict[str, Run]`` (added by
    # pipeline_model, so that a bad top-level key is reported before the runs inheriting it).
    _source_files: tuple[str, ...] = PrivateAttr(default=())

    @property
    def source_files(self) -> tuple[str, ...]:
        """The pipeline file and those it extends, as :func:`~cosim.config.load_pipeline`
        read them (none: a pipeline of the defaults and ``--set``)."""
        return self._source_files

    @model_validator(mode="after")
    def _bounded_plant_work(self) -> Pipeline:
        internal = self.plant.parameters.get("rk4_step")
        built = self.plant.builtin is not None or self.plant.urdf is not None
        if built and internal is not None and internal > 0:
            substeps = self.simulation.step / internal
            if substeps > self.simulation.max_plant_substeps:
                raise ValueError(
                    f"plant.parameters.rk4_step = {internal:g} s makes {substeps:,.0f} RK4 "
                    f"sub-steps per step of {self.simulation.step:g} s, more than "
                    f"simulation.max_plant_substeps = {self.simulation.max_plant_substeps}: "
                    f"use rk4_step ≥ {self.simulation.step / self.simulation.max_plant_substeps:g}"
                    " s, or raise max_plant_substeps if the run is meant to take that long")
        return self

    @model_validator(mode="before")
    @classmethod
    def _merge_runs(cls, data: Any) -> Any:
        """Each run inherits the top-level block tables, then overrides."""
        if not isinstance(data, dict):
            return data
        data = robot_defaults(data)
        runs = data.get("runs")
        if runs is not None and not isinstance(runs, dict):
            raise ValueError(f"runs must be a table of runs ([runs.NAME] ...), got {runs!r}")
        if not runs:
            data = {**data, "runs": {"default": {}}}
            runs = data["runs"]
        for name in runs:
            check_name(name, "run name")
        if isinstance(data.get("name"), str):
            check_name(data["name"], "pipeline name")
        merged = {}
        for name, spec in runs.items():
            if not isinstance(spec, dict):
                merged[name] = spec
                continue
            run = dict(spec)
            for section in BLOCKS:
                base = data.get(section, {})
                if isinstance(base, dict) and isinstance(run.get(section, {}), dict):
                    run[section] = {**base, **run.get(section, {})}
            for entry in run.get("blocks") or []:  # a named instance: over its kind's table
                if isinstance(entry, str) and " as " in entry:
                    instance, kind = chain_entry(entry)
                    base = data.get(kind, {})
                    if isinstance(base, dict) and isinstance(run.get(instance, {}), dict):
                        run[instance] = {**base, **run.get(instance, {})}
            merged[name] = run
        return {**data, "runs": merged}


_MODELS: dict[tuple, tuple[type[Pipeline], type[Run]]] = {}


def pipeline_model() -> tuple[type[Pipeline], type[Run]]:
    """The Pipeline and Run models for the blocks registered now (built once per registry
    state): every block's ``Params`` as a table, with its defaults, and ``[safety]`` with the
    keys packages registered (:func:`~cosim.declared.extend_safety`)."""
    load_entry_points()  # installed packages' blocks, before the first model is built
    safety = safety_section()  # [safety] with the keys packages add (the paper's barriers)
    key = (safety, *((kind, cls) for kind, cls in BLOCKS.items()))
    if key not in _MODELS:
        tables = {kind: (cls.Params, cls.Params()) for kind, cls in BLOCKS.items()}
        run = create_model("Run", __base__=Run, **tables)
        pipeline = create_model("Pipeline", __base__=Pipeline, safety=(safety, safety()),
                                **tables, runs=(dict[str, run], {}))
        _MODELS[key] = pipeline, run
    return _MODELS[key]
