"""Sweeps and Monte Carlo: one pipeline over a grid of values and/or seeded random samples of
any key ``--set`` accepts, every point run on Dask, one row per (point, run).

    cosim sweep pipelines/paper_safety.toml --grid controller.kv=20,40 --runs proposed
    cosim sweep P --sample 'plant.parameters."m[2]"=uniform(2.3,3.3)' --samples 500 --seed 1

Points: the Cartesian product of the grids; with samples, each grid point with ``--samples``
random draws (``uniform(a,b)``, ``normal(m,s)``, ``integers(a,b)``, seeded). Every point is
validated before anything runs. Each Dask worker keeps one plant FMU per file and mapping,
extracted once and ``reset()`` between points, and its compiled kernels stay loaded; short
points go a few to a task (Dask's own cost is per task). A point that diverges or whose FMU
fails is a row marked failed with its message; the sweep goes on. Ctrl-C keeps every
finished row. SI units, radians.

Modules: :mod:`.spec` (what a sweep is, its points), :mod:`.worker` (a point's rows, on a Dask
worker), :mod:`.execution` (the tasks), :mod:`.cluster` (the Dask cluster), :mod:`.checks`
(which checks make a row safe), :mod:`.tables` (rates, Wilson intervals, their text),
:mod:`.files` (results files, the plot), :mod:`.command` (``cosim sweep`` itself).
"""

from ..evaluate.reports import wilson
from .cluster import cluster_client
from .command import main
from .execution import MAX_POINTS_PER_TASK, STEPS_PER_TASK, execute, points_per_task
from .files import kept_share, write_safety_plot
from .spec import SweepError, SweepSpec, assignments, parse_grid, parse_sample, points
from .tables import safety_table
from .worker import run_point

__all__ = ["MAX_POINTS_PER_TASK", "STEPS_PER_TASK", "SweepError", "SweepSpec", "assignments",
           "cluster_client", "execute",
           "kept_share", "main", "parse_grid", "parse_sample", "points", "points_per_task",
           "run_point", "safety_table", "wilson", "write_safety_plot"]
