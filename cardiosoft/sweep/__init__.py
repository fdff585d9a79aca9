"""Design-space maps: metric-only sweeps over Omega x C (x afterload x bpm), at any scale.

    cardiosoft sweep --omega 1:5:64 --shortening 0.2:0.6:64 --afterload 60 --out maps/
    cardiosoft sweep ... --workers 2                   # a local Dask cluster
    cardiosoft sweep ... --scheduler tcp://host:8786   # a running Dask cluster

(``python -m cardiosoft.sweep`` is the same command.)

From Python, :func:`design_sweep` does the same and returns an ``xarray.Dataset``::

    import jax
    jax.config.update("jax_enable_x64", True)
    from cardiosoft.sweep import design_sweep

    ds = design_sweep("bench-dynamic", omega="1:5:64", shortening="0.2:0.6:64", afterload=60)
    ds.stroke_volume_ml.sel(afterload_mmHg=60, bpm=30).plot()

**What is computed.** Every point of the grid (the Cartesian product of the swept values) is a
member of the public batch solve (:func:`cardiosoft.batch.solve_beats`, ``save="metrics"``):
beat after beat to its periodic steady state (or exactly ``beats`` beats), keeping only the last
beat's metrics; no trace is ever stored.

**Chunks.** The grid is cut, in C order, into chunks of a fixed number of points (the last one
padded by repeating its last point, the padding dropped), so that one compiled solve serves
every chunk; memory follows the chunk size, not the grid. A chunk is a task: in this process by
default (the same function, no scheduler), or a task of Dask's distributed scheduler
(``workers=N`` starts a local cluster, ``scheduler=ADDRESS`` uses a running one: SSH,
Kubernetes, HPC job queues, anything Dask deploys on). On a worker the chunk is sharded over
all its JAX devices (:func:`~cardiosoft.batch.solve_beats` does that; a GPU when present).

**Robust.** A chunk that fails (NaN, the step limit, an exception, a worker lost) marks its
points ``steady = false`` with the reason in ``status`` and does not stop the sweep. With an
output folder each finished chunk is written at once (``DIR/sweep.partial/``); an interrupted
sweep keeps them, and ``resume=True`` (``--resume``) solves only the chunks that are missing.
Every file is written whole (a temporary file renamed into place) or not at all.

**Output.** ``DIR/sweep.nc`` (NetCDF 4, written with h5netcdf) holds the Dataset: dimensions
``omega``, ``shortening``, ``afterload_mmHg`` (water-column scenes) and ``bpm``; the metrics of
:data:`VARIABLES`, each with a ``units`` attribute; the scene, surrogate (name and sha256),
cardiosoft version and solver preset as attributes. ``DIR/map-*.png``: per afterload and bpm,
stroke volume, efficiency and peak force as heat maps over Omega x C, with the paper's Table I
designs and the buckling onset (``Omega C`` at the surrogate's buckling step) marked.

**A closed loop** with a soft pump (``soft-lv``, ``soft-rv``, ``tah``) is swept the same way,
every pump at the point's design; its variables are its ``summary.json`` numbers
(:func:`cardiosoft.network.loop_records.record_numbers`), its maps' panels a pump's stroke
volume, the cardiac output and the pump's peak force. Each kind of scene names its variables,
panels and flags (``sweep_variables``, ``sweep_panels``, ``sweep_flags`` of
:func:`cardiosoft.scene_tools.tools`).

**An svZeroDSolver model** with the pump in place of one of its chambers (``--scene model.json
--pump-chamber NAME``) is swept by :func:`cardiosoft.sweep.model.model_sweep`: the same grid of
designs, ``sweep.nc`` and maps, its variables the model's records by ``BLOCK.KEY``.

**Where it lives.** :mod:`~cardiosoft.sweep.plan` (the grid, its chunks, validation),
:mod:`~cardiosoft.sweep.chunk` (one chunk's task and solve, the variables, ``status``),
:mod:`~cardiosoft.sweep.executor` (this process or Dask), :mod:`~cardiosoft.sweep.store`
(unfinished sweeps, NetCDF), :mod:`~cardiosoft.sweep.maps` (figures),
:mod:`~cardiosoft.sweep.runner` (:func:`design_sweep`), :mod:`~cardiosoft.sweep.model` (a
model's sweep) and :mod:`~cardiosoft.sweep.cli`.
"""

from cardiosoft._validate import parse_values
from cardiosoft.sweep.chunk import (
    CHUNK_FAILED,
    MAX_STEPS,
    NONFINITE,
    NOT_STEADY,
    OK,
    SOLVER_FAILED,
    STATUS,
    VARIABLES,
)
from cardiosoft.sweep.cli import main
from cardiosoft.sweep.maps import map_name, plot_maps
from cardiosoft.sweep.plan import COORDS, DEFAULT_CHUNK, DIMS
from cardiosoft.sweep.runner import design_sweep
from cardiosoft.sweep.store import OUTPUT, PARTIAL, flat_range_boxes

__all__ = [
    "CHUNK_FAILED",
    "COORDS",
    "DEFAULT_CHUNK",
    "DIMS",
    "MAX_STEPS",
    "NONFINITE",
    "NOT_STEADY",
    "OK",
    "OUTPUT",
    "PARTIAL",
    "SOLVER_FAILED",
    "STATUS",
    "VARIABLES",
    "design_sweep",
    "flat_range_boxes",
    "main",
    "map_name",
    "parse_values",
    "plot_maps",
]
