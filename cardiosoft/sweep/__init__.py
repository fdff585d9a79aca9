"""Design-space maps: metric-only sweeps over Omega x C (x afterload x bpm), at any scale.

    python -m cardiosoft.sweep --omega 1:5:64 --shortening 0.2:0.6:64 --afterload 60 --out maps/
    python -m cardiosoft.sweep ... --workers 2                   # a local Dask cluster
    python -m cardiosoft.sweep ... --scheduler tcp://host:8786   # a running Dask cluster

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
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import itertools
import json
import math
import os
import shutil
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from cardiosoft.units import ml

__all__ = [
    "DIMS",
    "OUTPUT",
    "STATUS",
    "VARIABLES",
    "design_sweep",
    "main",
    "parse_values",
    "plot_maps",
]

OUTPUT = "sweep.nc"
"""The Dataset's file in the output folder."""
PARTIAL = "sweep.partial"
"""Folder of the finished chunks of a sweep that is not done yet (removed when it is)."""
DEFAULT_CHUNK = 1024
"""Points per chunk (one compiled batch solve); see ``benchmarks/sweep_throughput.py``."""
DIMS = ("omega", "shortening", "afterload_mmHg", "bpm")
"""The swept variables, in the order of the Dataset's dimensions (``afterload_mmHg`` only for a
water-column scene)."""
COORDS = {
    "omega": ("1", "helix parameter Omega (n = Omega / 4 turns of each cable)"),
    "shortening": ("1", "cable shortening C = (L - l) / L"),
    "afterload_mmHg": ("mmHg", "water-column head at the pump base before the pull"),
    "bpm": ("1/min", "beats per minute"),
}
STATUS = ("ok", "not_steady", "max_steps_reached", "nonfinite", "solver_failed", "chunk_failed")
"""The values of the ``status`` variable (its ``flag_meanings``): 0 ok; 1 the solver finished
but the cycle-to-cycle change is above the scene's tolerance; 2 the step limit was hit; 3 the
solver finished with a NaN or infinite metric; 4 another solver failure; 5 the chunk raised
or its worker was lost (the chunk's message is in the Dataset's ``failed_chunks`` attribute)."""
OK, NOT_STEADY, MAX_STEPS, NONFINITE, SOLVER_FAILED, CHUNK_FAILED = range(len(STATUS))

# name: (BeatMetrics field, scale to the unit, unit, long name). The five the issue asks for
# first; every one is in the last beat of the member.
_METRICS = {
    "stroke_volume_ml": (
        "stroke_volume",
        ml,
        "ml",
        "stroke volume EDV - ESV (the bench: the peak column rise, the paper's dynamic SV)",
    ),
    "ejection_fraction": ("ejection_fraction", 1.0, "1", "ejection fraction SV / EDV"),
    "peak_force_N": ("peak_force", 1.0, "N", "largest measured cable force during the pull"),
    "mech_work_J": (
        "mech_work",
        1.0,
        "J",
        "mechanical work: the cable force integrated over the pull (the paper's M)",
    ),
    "efficiency": ("efficiency", 1.0, "1", "the paper's efficiency P_a SV / M"),
    "hydraulic_work_J": ("hydraulic_work_paper", 1.0, "J", "the paper's hydraulic work P_a SV"),
    "stroke_work_J": ("stroke_work", 1.0, "J", "area of the pressure-volume loop"),
    "edv_ml": ("edv", ml, "ml", "end-diastolic (largest) pump volume"),
    "esv_ml": ("esv", ml, "ml", "end-systolic (smallest) pump volume"),
    "cardiac_output_l_min": (
        "cardiac_output",
        1000 * ml / 60.0,
        "l/min",
        "cardiac output SV / period",
    ),
}
_SOLVER = {
    "beats": ("i4", "1", "beats integrated"),
    "steady": (
        "bool",
        "1",
        "at the periodic steady state (the last beat's cycle-to-cycle change within the "
        "attribute steady_tol, also with a fixed number of beats), the solver successful and "
        "every metric finite",
    ),
    "residual": (
        "f8",
        "1",
        "largest cycle-to-cycle change of a periodic state over the last beat, each state in "
        "its own unit (ml, ml/s or mmHg), held to the attribute steady_tol",
    ),
    "volume_drift": ("f8", "1", "largest relative drift of the total fluid volume"),
    "num_steps": ("i4", "1", "solver steps of the last beat"),
    "status": ("i1", "1", "what became of the point: " + ", ".join(STATUS)),
}
VARIABLES = (*_METRICS, *_SOLVER)
"""The data variables of the Dataset, each with ``units`` and ``long_name`` attributes."""


# ------------------------------------------------------------------------------ the plan


def parse_values(value, name: str) -> tuple[float, ...]:
    """The values of one swept variable: ``"START:STOP:N"`` (N points from START to STOP, both
    included), one number, or a sequence of numbers. ``ValueError`` names ``name``."""
    if isinstance(value, str):
        parts = value.split(":")
        try:
            numbers = [float(p) for p in parts]
        except ValueError:
            numbers = None
        if numbers is None or len(parts) not in (1, 3):
            raise ValueError(
                f"{name} = {value!r}: allowed START:STOP:N (N points from START to STOP) or "
                "one number"
            )
        if len(parts) == 1:
            values = numbers
        else:
            start, stop, n = numbers
            if n != int(n) or n < 1:
                raise ValueError(f"{name} = {value!r}: N = {parts[2]} must be a whole number >= 1")
            if int(n) > 1 and start == stop:
                raise ValueError(
                    f"{name} = {value!r}: an empty range (START = STOP with N > 1 points)"
                )
            values = np.linspace(start, stop, int(n)).tolist()
    else:
        try:
            values = [float(v) for v in np.atleast_1d(np.asarray(value, dtype=float)).ravel()]
        except (TypeError, ValueError):
            raise ValueError(f"{name} = {value!r}: allowed numbers or START:STOP:N") from None
    if not values:
        raise ValueError(f"{name}: an empty range; give at least one value")
    if len(set(values)) != len(values):
        raise ValueError(f"{name} = {value!r}: the values repeat; give each value once")
    return tuple(values)


@dataclasses.dataclass(frozen=True)
class _Plan:
    """A validated sweep: the scene, the grid, the beats, the chunks and the surrogate."""

    scene: object  # cardiosoft.scene.Scene
    coords: dict  # dim -> tuple of values (user units), in DIMS order
    beats: int | None
    chunk: int
    pump: object  # None (shipped), a path, or a PumpSurrogate with numpy leaves
    surrogate: str
    surrogate_sha256: str
    precision: str

    @property
    def shape(self) -> tuple[int, ...]:
        return tuple(len(v) for v in self.coords.values())

    @property
    def size(self) -> int:
        return math.prod(self.shape)

    @property
    def n_chunks(self) -> int:
        return -(-self.size // self.chunk)

    def members(self, index: int) -> tuple[dict, int]:
        """The member values (SI) of chunk ``index``, padded to the chunk size; valid count."""
        from cardiosoft.units import mmHg

        start = index * self.chunk
        stop = min(start + self.chunk, self.size)
        flat = np.arange(start, stop)
        flat = np.concatenate([flat, np.full(self.chunk - len(flat), stop - 1)])
        where = np.unravel_index(flat, self.shape)
        members = {}
        for dim, idx in zip(self.coords, where, strict=True):
            values = np.asarray(self.coords[dim], dtype=float)[idx]
            key = {"afterload_mmHg": "afterload"}.get(dim, dim)
            members[key] = values * mmHg if dim == "afterload_mmHg" else values
        return members, stop - start

    def identity(self) -> dict:
        """What must match for ``resume`` to continue a sweep (JSON-ready)."""
        return {
            "format": 1,
            "scene": dataclasses.asdict(self.scene),
            "coords": {k: list(v) for k, v in self.coords.items()},
            "beats": self.beats,
            "chunk": self.chunk,
            "surrogate": self.surrogate,
            "surrogate_sha256": self.surrogate_sha256,
            "precision": self.precision,
            "cardiosoft_version": _version(),
        }

    def attrs(self) -> dict:
        """The Dataset's attributes."""
        from cardiosoft.batch import default_config

        scene = self.scene
        config = default_config(scene)
        solver = type(config.solver).__name__
        return {
            "title": f"cardiosoft design-space sweep of scene {scene.name}",
            "scene": scene.name,
            "scene_source": str(scene.source),
            "scene_description": scene.description,
            "scene_parameters": json.dumps(dataclasses.asdict(scene)),  # SI, as Scene holds it
            "surrogate": self.surrogate,
            "surrogate_sha256": self.surrogate_sha256,
            "cardiosoft_version": _version(),
            "solver_preset": scene.accuracy,
            "solver": f"{solver}, rtol {float(config.rtol):g}, atol {float(config.atol):g}, "
            f"max_steps {config.max_steps}",
            "beats_mode": "steady" if self.beats is None else "fixed",
            "max_beats": scene.max_beats if self.beats is None else self.beats,
            "steady_tol": scene.steady_tol,
            "precision": self.precision,
            "chunk": self.chunk,
            "status_meanings": " ".join(STATUS),
        }


def _version() -> str:
    return sys.modules["cardiosoft"].__version__  # the package is imported before this module


def _plan(
    scene, omega, shortening, afterload, bpm, beats, accuracy, chunk, pump, precision
) -> _Plan:
    from cardiosoft._validate import check_range
    from cardiosoft.experiment import configure
    from cardiosoft.scene import RANGES

    scene = configure(scene, accuracy=accuracy)
    if scene.static:
        raise ValueError(
            f"scene {scene.name} is static (no beats to simulate): sweep a dynamic scene "
            "such as bench-dynamic"
        )
    coords = {
        "omega": parse_values(omega, "omega"),
        "shortening": parse_values(shortening, "shortening"),
    }
    check_range("omega", coords["omega"], "", *RANGES["omega"])
    check_range("shortening C", coords["shortening"], "", *RANGES["shortening"])
    if scene.afterload.has_heads:
        from cardiosoft.units import mmHg

        heads = (
            tuple(h / mmHg for h in scene.afterloads)
            if afterload is None
            else parse_values(afterload, "afterload")
        )
        check_range("afterload", heads, "mmHg", *RANGES["afterloads"])
        coords["afterload_mmHg"] = heads
    elif afterload is not None:
        raise ValueError(
            f"afterload: scene {scene.name} has a {scene.afterload_type} afterload, which has "
            "no column head to sweep"
        )
    coords["bpm"] = (scene.bpm,) if bpm is None else parse_values(bpm, "bpm")
    check_range("bpm", coords["bpm"], "bpm", *RANGES["bpm"], lo_open=True)
    if beats is not None:
        if isinstance(beats, bool) or not isinstance(beats, int | np.integer):
            raise ValueError(f"beats = {beats!r}: allowed a whole number in [1, 500]")
        check_range("beats", beats, "beats", 1, 500)
        beats = int(beats)
    if isinstance(chunk, bool) or not isinstance(chunk, int | np.integer) or chunk < 1:
        raise ValueError(f"chunk = {chunk!r}: allowed a whole number of points >= 1")
    size = math.prod(len(v) for v in coords.values())
    chunk = int(min(chunk, size))  # a small grid is one chunk of its own size
    pump, name, digest = _surrogate(pump)
    return _Plan(scene, coords, beats, chunk, pump, name, digest, precision)


def _surrogate(pump):
    """(what a task carries, name, sha256) of the shipped surrogate, a path or an object."""
    from cardiosoft import pump as pump_module

    if pump is None or isinstance(pump, str | os.PathLike):
        card = pump_module.load_card(pump)
        if pump is not None:
            pump_module.load(pump)  # checks the file and its hash now, not on a worker
            pump = str(Path(pump).resolve())
        return pump, card["name"], card["weights_sha256"]
    if not isinstance(pump, pump_module.PumpSurrogate):
        raise ValueError(f"pump = {pump!r}: allowed None, a surrogate file or a PumpSurrogate")
    import hashlib

    import jax

    leaves = [np.asarray(leaf) for leaf in jax.tree_util.tree_leaves(pump)]
    digest = hashlib.sha256(b"".join(leaf.tobytes() for leaf in leaves)).hexdigest()
    # numpy leaves travel to a worker unchanged; JAX arrays would arrive in its precision
    return jax.tree_util.tree_map(np.asarray, pump), "in-memory PumpSurrogate", digest


# ------------------------------------------------------------------------------ one chunk


@dataclasses.dataclass(frozen=True)
class _Task:
    """Everything a worker needs to solve one chunk (picklable, small)."""

    index: int
    scene: object
    members: dict
    valid: int
    beats: int | None
    pump: object
    x64: bool


_PUMPS: dict = {}


def _load_pump(ref):
    from cardiosoft.pump import load

    if ref is None or isinstance(ref, str):
        if ref not in _PUMPS:
            _PUMPS[ref] = load(ref)
        return _PUMPS[ref]
    return ref


def _failed(n: int, message: str) -> dict:
    out = {name: np.full(n, np.nan) for name in _METRICS}
    out |= {
        "beats": np.zeros(n, np.int32),
        "steady": np.zeros(n, bool),
        "residual": np.full(n, np.nan),
        "volume_drift": np.full(n, np.nan),
        "num_steps": np.zeros(n, np.int32),
        "status": np.full(n, CHUNK_FAILED, np.int8),
        "error": np.array(message),
    }
    return out


def _solve_chunk(task: _Task) -> dict:
    """Solve one chunk: numpy arrays of its valid points (``error``: "" or why it failed).

    Runs on a Dask worker as well as in this process: it switches the worker's JAX to the
    caller's precision, and it never raises for a failed solve.
    """
    import jax

    if bool(jax.config.jax_enable_x64) != task.x64:
        jax.config.update("jax_enable_x64", task.x64)
    try:
        import diffrax

        from cardiosoft.batch import solve_beats

        n = task.valid
        members = dict(task.members)
        devices = len(jax.devices())
        size = len(next(iter(members.values())))
        if size % devices:  # shard evenly over the worker's devices: pad once more
            pad = devices - size % devices
            members = {k: np.concatenate([v, np.repeat(v[-1:], pad)]) for k, v in members.items()}
        out = solve_beats(
            task.scene,
            **members,
            beats=task.beats,
            save="metrics",
            pump=_load_pump(task.pump),
        )
        out = jax.block_until_ready(out)
        result = {}
        for name, (field, scale, _, _) in _METRICS.items():
            result[name] = np.asarray(getattr(out.metrics, field))[:n] / scale
        finite = np.all([np.isfinite(v) for v in result.values()], axis=0)
        succeeded = np.asarray(out.succeeded)[:n]
        max_steps = np.asarray(out.result == diffrax.RESULTS.max_steps_reached)[:n]
        steady = np.asarray(out.steady)[:n]
        status = np.select(
            [~succeeded & max_steps, ~succeeded, ~finite, ~steady],
            [MAX_STEPS, SOLVER_FAILED, NONFINITE, NOT_STEADY],
            OK,
        ).astype(np.int8)
        for name in _METRICS:  # a failed solve leaves no number worth keeping
            result[name] = np.where(succeeded, result[name], np.nan)
        result |= {
            "beats": np.asarray(out.beats)[:n].astype(np.int32),
            "steady": status == OK,
            "residual": np.asarray(out.residual)[:n].astype(float),
            "volume_drift": np.asarray(out.volume_drift)[:n].astype(float),
            "num_steps": np.asarray(out.num_steps)[:n].astype(np.int32),
            "status": status,
            "error": np.array(""),
        }
        return result
    except Exception as err:  # a failed chunk must not stop the sweep
        return _failed(task.valid, f"{type(err).__name__}: {err}".splitlines()[0])


# ------------------------------------------------------------------------------ where chunks run


def _run_here(tasks) -> Iterator[tuple[int, dict]]:
    for task in tasks:
        yield task.index, _solve_chunk(task)


def _run_dask(client, tasks, window: int) -> Iterator[tuple[int, dict]]:
    """Chunks as Dask tasks, at most ``window`` in flight (the client holds no more)."""
    from distributed import as_completed

    tasks = iter(tasks)
    pending = {}

    def submit():
        task = next(tasks, None)
        if task is None:
            return None
        future = client.submit(_solve_chunk, task, pure=False, key=f"cardiosoft-chunk-{task.index}")
        pending[future.key] = task
        return future

    futures = [f for f in (submit() for _ in range(window)) if f is not None]
    queue = as_completed(futures, loop=client.loop)
    for future in queue:
        task = pending.pop(future.key)
        try:
            result = future.result()
        except Exception as err:  # a lost worker fails its chunk, not the sweep
            result = _failed(task.valid, f"{type(err).__name__}: {err}".splitlines()[0])
        future.release()
        yield task.index, result
        nxt = submit()
        if nxt is not None:
            queue.add(nxt)


@contextlib.contextmanager
def _executor(workers, scheduler, client):
    """(a function running tasks, how it is described) for the chosen place."""
    if client is not None:
        yield (lambda tasks: _run_dask(client, tasks, _window(client))), "a Dask client"
        return
    if workers is None and scheduler is None:
        import jax

        devices = jax.devices()
        yield _run_here, f"this process on {len(devices)} {devices[0].platform.upper()} device(s)"
        return
    import logging

    from distributed import Client, LocalCluster

    if scheduler is not None:
        try:
            own = Client(scheduler, timeout="10s", set_as_default=False)
        except (OSError, TimeoutError, ValueError) as err:
            raise ValueError(
                f"--scheduler {scheduler}: cannot reach a Dask scheduler there ({err})"
            ) from None
        where = f"the Dask scheduler at {scheduler}"
        cluster = None
    else:
        cluster = LocalCluster(
            n_workers=workers,
            threads_per_worker=1,
            processes=True,
            dashboard_address=None,
            silence_logs=logging.ERROR,
        )
        own = Client(cluster, set_as_default=False)
        where = f"a local Dask cluster of {workers} worker processes"
    try:
        yield (lambda tasks: _run_dask(own, tasks, _window(own))), where
    finally:
        own.close()
        if cluster is not None:
            cluster.close()


def _window(client) -> int:
    threads = sum(client.nthreads().values()) or 1
    return max(4, 2 * threads)


# ------------------------------------------------------------------------------ files


def _boxes(start: int, stop: int, shape) -> list[tuple[slice, ...]]:
    """Hyper-rectangles that together are the C-order flat index range [start, stop) of an
    array of ``shape``, in order (at most 2 per dimension)."""
    if start >= stop:
        return []
    if len(shape) == 1:
        return [(slice(start, stop),)]
    inner = math.prod(shape[1:])
    i0, r0 = divmod(start, inner)
    i1, r1 = divmod(stop, inner)
    if i0 == i1:
        return [(slice(i0, i0 + 1), *b) for b in _boxes(r0, r1, shape[1:])]
    out = []
    if r0:
        out += [(slice(i0, i0 + 1), *b) for b in _boxes(r0, inner, shape[1:])]
        i0 += 1
    if i1 > i0:
        out.append((slice(i0, i1), *(slice(0, n) for n in shape[1:])))
    if r1:
        out += [(slice(i1, i1 + 1), *b) for b in _boxes(0, r1, shape[1:])]
    return out


class _Partial:
    """The finished chunks of an unfinished sweep: ``spec.json`` and ``chunk-NNNNNN.npz``."""

    def __init__(self, folder: Path):
        self.folder = folder

    def exists(self) -> bool:
        return (self.folder / "spec.json").is_file()

    def start(self, identity: dict) -> None:
        from cardiosoft.files import atomic_path

        self.folder.mkdir(parents=True, exist_ok=True)
        with atomic_path(self.folder / "spec.json") as tmp:
            tmp.write_text(json.dumps(identity, indent=1, sort_keys=True) + "\n")

    def check(self, identity: dict) -> None:
        """``ValueError`` naming the first setting that differs from the one on disk."""
        try:
            old = json.loads((self.folder / "spec.json").read_text())
        except (OSError, ValueError) as err:
            raise ValueError(f"{self.folder}: cannot read the unfinished sweep ({err})") from None
        new = json.loads(json.dumps(identity))
        for key in sorted(set(old) | set(new)):
            if json.dumps(old.get(key), sort_keys=True) != json.dumps(new.get(key), sort_keys=True):
                raise ValueError(
                    f"--resume: the unfinished sweep in {self.folder.parent} was started with "
                    f"another {key}; pass --force to start over"
                )

    def path(self, index: int) -> Path:
        return self.folder / f"chunk-{index:06d}.npz"

    def done(self) -> set[int]:
        return {int(p.stem.split("-")[1]) for p in self.folder.glob("chunk-*.npz")}

    def save(self, index: int, result: dict) -> None:
        from cardiosoft.files import atomic_path

        with atomic_path(self.path(index)) as tmp, open(tmp, "wb") as f:
            np.savez(f, **result)

    def load(self, index: int) -> dict:
        with np.load(self.path(index), allow_pickle=False) as z:
            return {k: z[k] for k in z.files}


def _write_netcdf(plan: _Plan, chunks, path: Path, failed: dict) -> None:
    """Write the Dataset to ``path`` chunk by chunk (h5netcdf; xarray's conventions, so that
    ``xarray.open_dataset`` reads ``steady`` back as bool and NaN as the fill value)."""
    import h5netcdf

    dims = tuple(plan.coords)
    attrs = plan.attrs()
    if failed:
        attrs["failed_chunks"] = "; ".join(f"chunk {i}: {m}" for i, m in sorted(failed.items()))
    with h5netcdf.File(path, "w") as f:
        f.dimensions = {d: len(v) for d, v in plan.coords.items()}
        for d, values in plan.coords.items():
            v = f.create_variable(d, (d,), data=np.asarray(values, dtype=float))
            v.attrs["units"], v.attrs["long_name"] = COORDS[d]
        variables = {}
        for name, (_, _, units, long_name) in _METRICS.items():
            variables[name] = f.create_variable(name, dims, dtype="f8", fillvalue=np.nan)
            variables[name].attrs.update(units=units, long_name=long_name)
        for name, (dtype, units, long_name) in _SOLVER.items():
            if dtype == "f8":
                var = f.create_variable(name, dims, dtype="f8", fillvalue=np.nan)
            else:
                var = f.create_variable(name, dims, dtype="i1" if dtype == "bool" else dtype)
            var.attrs.update(units=units, long_name=long_name)
            if dtype == "bool":
                var.attrs["dtype"] = "bool"  # xarray's encoding of a bool variable
            variables[name] = var
        variables["status"].attrs["flag_values"] = np.arange(len(STATUS), dtype=np.int8)
        variables["status"].attrs["flag_meanings"] = " ".join(STATUS)
        f.attrs.update(attrs)
        for index, result in chunks:
            start = index * plan.chunk
            offset = 0
            for box in _boxes(start, start + len(result["status"]), plan.shape):
                shape = tuple(s.stop - s.start for s in box)
                n = math.prod(shape)
                for name, var in variables.items():
                    values = result[name][offset : offset + n].reshape(shape)
                    var[box] = values.astype(np.int8) if name == "steady" else values
                offset += n


# ------------------------------------------------------------------------------ maps


def _edges(values) -> np.ndarray:
    v = np.asarray(values, dtype=float)
    if len(v) == 1:
        return np.array([v[0] - 0.05, v[0] + 0.05])
    mid = 0.5 * (v[1:] + v[:-1])
    return np.concatenate([[2 * v[0] - mid[0]], mid, [2 * v[-1] - mid[-1]]])


def map_name(afterload_mmHg: float | None, bpm: float) -> str:
    """The file name of the map at one afterload (None: a Windkessel scene) and rate."""
    head = "" if afterload_mmHg is None else f"{afterload_mmHg:g}mmHg-"
    return f"map-{head}{bpm:g}bpm.png"


def _map_keys(coords: dict) -> list[tuple[float | None, float]]:
    heads = coords.get("afterload_mmHg", (None,))
    return list(itertools.product(heads, coords["bpm"]))


def plot_maps(ds, out_dir, onset_twist: float | None = None) -> list[Path]:
    """One figure per afterload and bpm: stroke volume, efficiency and peak force over Omega x
    C, with the paper's Table I designs and the buckling onset ``Omega C = onset_twist``
    (default: :data:`cardiosoft.pump.BUCKLING_ONSET`) marked; points that are not steady are
    crossed. Files are named by :func:`map_name`; returns their paths."""
    import matplotlib

    from cardiosoft.datasets import load_paper_data
    from cardiosoft.pump import BUCKLING_ONSET

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib import patheffects

    twist = BUCKLING_ONSET[0] if onset_twist is None else onset_twist
    table1 = load_paper_data().table1_fem
    omega, c = np.asarray(ds["omega"]), np.asarray(ds["shortening"])
    x_edges, y_edges = _edges(omega), _edges(c)
    inside = (
        (table1["omega"] >= x_edges[0])
        & (table1["omega"] <= x_edges[-1])
        & (table1["shortening"] >= y_edges[0])
        & (table1["shortening"] <= y_edges[-1])
    )
    panels = (
        ("stroke_volume_ml", "stroke volume [ml]", "viridis"),
        ("efficiency", "efficiency P_a SV / M [-]", "magma"),
        ("peak_force_N", "peak cable force [N]", "cividis"),
    )
    written = []
    coords = {d: tuple(np.asarray(ds[d]).tolist()) for d in ds.dims}
    for head, rate in _map_keys(coords):
        sel = {"bpm": rate} | ({} if head is None else {"afterload_mmHg": head})
        cut = ds[[p[0] for p in panels] + ["steady"]].sel(sel).load()
        steady = np.asarray(cut["steady"].transpose("omega", "shortening"))
        fig, axes = plt.subplots(1, 3, figsize=(14, 4.3), constrained_layout=True)
        for ax, (name, label, cmap) in zip(axes, panels, strict=True):
            z = np.asarray(cut[name].transpose("omega", "shortening"), dtype=float)
            mesh = ax.pcolormesh(x_edges, y_edges, z.T, cmap=cmap, shading="flat")
            bar = fig.colorbar(mesh, ax=ax, label=label)
            if min(z.shape) >= 3 and np.isfinite(z).sum() >= 9:  # contours crowd at the step
                lines = ax.contour(omega, c, z.T, levels=8, colors="k", linewidths=0.5)
                bar.add_lines(lines)
            bad = ~steady
            if bad.any():
                oo, cc = np.meshgrid(omega, c, indexing="ij")
                ax.plot(oo[bad], cc[bad], "x", color="0.6", ms=3, label="not steady")
            o_line = np.linspace(max(x_edges[0], 1e-9), x_edges[-1], 400)
            c_line = twist / o_line
            c_line[(c_line < y_edges[0]) | (c_line > y_edges[-1])] = np.nan
            if np.isfinite(c_line).any():
                ax.plot(
                    o_line,
                    c_line,
                    "w--",
                    lw=1.6,
                    path_effects=[patheffects.withStroke(linewidth=3, foreground="k")],
                    label=f"buckling onset Omega C = {twist:g}",
                )
            if inside.any():
                ax.plot(
                    table1["omega"][inside],
                    table1["shortening"][inside],
                    "o",
                    mfc="none",
                    mec="red",
                    ms=6,
                    label="paper Table I designs",
                )
            ax.set_xlim(x_edges[0], x_edges[-1])
            ax.set_ylim(y_edges[0], y_edges[-1])
            ax.set_xlabel("helix parameter Omega [-]")
            ax.set_ylabel("cable shortening C [-]")
            ax.set_title(label.split(" [")[0])
        handles, labels = axes[0].get_legend_handles_labels()
        if handles:
            fig.legend(
                handles,
                labels,
                loc="lower center",
                ncol=3,
                fontsize=8,
                frameon=False,
                bbox_to_anchor=(0.5, -0.08),
            )
        where = "" if head is None else f"{head:g} mmHg, "
        n_ok, n = int(steady.sum()), steady.size
        fig.suptitle(
            f"{ds.attrs.get('scene', '')}: {where}{rate:g} bpm ({n_ok} of {n} points steady)"
        )
        path = Path(out_dir) / map_name(head, rate)
        tmp = path.with_name(f".{path.name}.tmp")  # written whole, then renamed into place
        try:
            fig.savefig(tmp, format="png", dpi=110, bbox_inches="tight")
            tmp.replace(path)
        finally:
            plt.close(fig)
            tmp.unlink(missing_ok=True)
        written.append(path)
    return written


# ------------------------------------------------------------------------------ the sweep


def _progress(plan: _Plan, todo: int, enabled: bool):
    from tqdm.auto import tqdm

    return tqdm(
        total=plan.size,
        initial=plan.size - todo,
        unit="pt",
        desc="points",
        disable=not enabled,
        file=sys.stderr,
        mininterval=1.0,
        smoothing=0.1,
        dynamic_ncols=True,
    )


def design_sweep(
    scene="bench-dynamic",
    *,
    omega,
    shortening,
    afterload=None,
    bpm=None,
    beats: int | None = None,
    accuracy: str | None = None,
    out=None,
    chunk: int = DEFAULT_CHUNK,
    workers: int | None = None,
    scheduler: str | None = None,
    client=None,
    resume: bool = False,
    force: bool = False,
    maps: bool = True,
    progress: bool = True,
    pump=None,
    log=None,
):
    """Simulate every point of a grid of designs, afterloads and rates; metrics only.

    **Arguments** (user units; the module docstring says what happens):

    - ``scene``: a shipped scene's name, a scene file or a :class:`~cardiosoft.scene.Scene`.
    - ``omega``, ``shortening``: the design grid: ``"START:STOP:N"``, one number, or a
      sequence of values.
    - ``afterload``: column heads in mmHg, in the same forms (water-column scenes; default the
      scene's); ``bpm``: rates (default the scene's).
    - ``beats``: exactly this many beats, in [1, 500] (default: to the steady state).
    - ``accuracy``: the solver preset, ``"fast"``, ``"default"`` or ``"reference"`` (default
      the scene's).
    - ``out``: output folder for ``sweep.nc`` and the maps (``maps=False``: no maps); None
      writes nothing and returns the Dataset in memory.
    - ``chunk``: points per chunk (one compiled batch); memory follows it.
    - ``workers``: start a local Dask cluster of that many processes; ``scheduler``: the
      address of a running Dask scheduler; ``client``: a ``distributed.Client`` of your own.
      None of them: the chunks run in this process.
    - ``resume``: continue the unfinished sweep in ``out``; ``force``: overwrite its outputs
      (and, without ``resume``, start an unfinished one over).
    - ``progress``: a progress bar on stderr; ``pump``: a surrogate file or
      :class:`~cardiosoft.pump.PumpSurrogate` (default the shipped one); ``log``: a function
      that gets one-line messages (default: none).

    **Returns:** the ``xarray.Dataset`` (module docstring); with ``out``, opened lazily from
    ``out/sweep.nc``. Bad input raises ``ValueError`` before anything is written or solved.
    """
    import jax
    import xarray as xr

    from cardiosoft.files import refuse_overwrite

    say = log or (lambda message: None)
    if workers is not None and (
        isinstance(workers, bool) or not isinstance(workers, int | np.integer) or workers < 1
    ):
        raise ValueError(f"workers = {workers!r}: allowed a whole number >= 1")
    if sum(x is not None for x in (workers, scheduler, client)) > 1:
        raise ValueError("give at most one of workers, scheduler and client")
    precision = "float64" if jax.config.jax_enable_x64 else "float32"
    plan = _plan(scene, omega, shortening, afterload, bpm, beats, accuracy, chunk, pump, precision)
    out_dir = None if out is None else Path(out)
    partial = None
    done: set[int] = set()
    if out_dir is not None:
        if out_dir.exists() and not out_dir.is_dir():
            raise ValueError(f"out {out_dir} exists and is not a folder")
        names = [OUTPUT] + ([map_name(*k) for k in _map_keys(plan.coords)] if maps else [])
        for name in names:
            refuse_overwrite(out_dir / name, force)
        partial = _Partial(out_dir / PARTIAL)
        if partial.exists():
            if resume:
                partial.check(plan.identity())
                done = partial.done() & set(range(plan.n_chunks))
            elif not force:
                raise ValueError(
                    f"{out_dir} holds an unfinished sweep ({PARTIAL}/): pass --resume to "
                    "continue it or --force to start over"
                )
    elif resume:
        raise ValueError("resume needs an output folder (out) holding the unfinished sweep")

    with _executor(workers, scheduler, client) as (run, where):
        if partial is not None:
            if not resume or not partial.exists():
                if partial.folder.exists():
                    shutil.rmtree(partial.folder)
                partial.start(plan.identity())
        todo = [i for i in range(plan.n_chunks) if i not in done]
        say(
            f"{plan.scene.name}: {plan.size} points ({' x '.join(map(str, plan.shape))} "
            f"{' x '.join(plan.coords)}) in {plan.n_chunks} chunks of {plan.chunk}"
            + (f", {len(done)} done already" if done else "")
            + f"; solving in {where} ..."
        )
        kept: dict[int, dict] = {}
        x64 = precision == "float64"

        def tasks():
            for i in todo:
                members, valid = plan.members(i)
                yield _Task(i, plan.scene, members, valid, plan.beats, plan.pump, x64)

        start = time.perf_counter()
        beats_run = 0
        with _progress(plan, sum(_chunk_len(plan, i) for i in todo), progress) as bar:
            for index, result in run(tasks()):
                if partial is not None:
                    partial.save(index, result)
                else:
                    kept[index] = result
                beats_run += int(np.sum(result["beats"]))
                elapsed = max(time.perf_counter() - start, 1e-9)
                bar.set_postfix_str(f"{beats_run / elapsed:,.0f} beats/s", refresh=False)
                bar.update(len(result["status"]))
                if result["error"].item():
                    say(f"chunk {index} failed: {result['error'].item()}")
        elapsed = time.perf_counter() - start
        if todo:
            say(
                f"solved {sum(_chunk_len(plan, i) for i in todo)} points in {elapsed:.1f} s "
                f"({beats_run / max(elapsed, 1e-9):,.0f} beats/s)"
            )

    def chunks():
        for i in range(plan.n_chunks):
            yield i, (partial.load(i) if partial is not None else kept[i])

    failed = {}
    for i in range(plan.n_chunks):
        error = (partial.load(i) if partial is not None else kept[i])["error"].item()
        if error:
            failed[i] = error
    if out_dir is None:
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / OUTPUT
            _write_netcdf(plan, chunks(), path, failed)
            return xr.load_dataset(path, engine="h5netcdf")
    staging = Path(tempfile.mkdtemp(dir=out_dir, prefix=".staging-"))
    try:
        _write_netcdf(plan, chunks(), staging / OUTPUT, failed)
        written = [OUTPUT]
        if maps:
            with xr.open_dataset(staging / OUTPUT, engine="h5netcdf") as ds:
                written += [p.name for p in plot_maps(ds, staging)]
        for name in written:
            (staging / name).replace(out_dir / name)
            say(f"wrote {out_dir / name}")
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    shutil.rmtree(partial.folder, ignore_errors=True)
    return xr.open_dataset(out_dir / OUTPUT, engine="h5netcdf")


def _chunk_len(plan: _Plan, index: int) -> int:
    return min(plan.chunk, plan.size - index * plan.chunk)


# ------------------------------------------------------------------------------ command line


class _Parser(argparse.ArgumentParser):
    def error(self, message):
        """Bad arguments: one line and exit status 2, like every other bad input."""
        print(f"error: {message} (see {self.prog} --help)", file=sys.stderr)
        raise SystemExit(2)


def _parser() -> argparse.ArgumentParser:
    from cardiosoft.scene import ACCURACY, SCENE_NAMES

    p = _Parser(
        prog="python -m cardiosoft.sweep",
        description="Design-space maps: simulate every point of a grid of designs (Omega x C), "
        "afterloads and rates to its periodic steady state, keeping metrics only; write an "
        "xarray Dataset (sweep.nc) and heat maps.",
    )
    p.add_argument(
        "--scene",
        default="bench-dynamic",
        help=f"shipped scene ({', '.join(s for s in SCENE_NAMES if s != 'bench-static')}) or "
        "a scene .toml file (default: bench-dynamic)",
    )
    p.add_argument("--omega", required=True, metavar="START:STOP:N", help="helix parameter grid")
    p.add_argument(
        "--shortening", required=True, metavar="START:STOP:N", help="cable shortening C grid"
    )
    p.add_argument(
        "--afterload",
        nargs="+",
        metavar="MMHG",
        help="water-column heads in mmHg (default: the scene's); START:STOP:N allowed too",
    )
    p.add_argument(
        "--bpm", nargs="+", metavar="BPM", help="beats per minute (default: the scene's)"
    )
    p.add_argument("--beats", type=int, help="run exactly this many beats (default: until steady)")
    p.add_argument("--accuracy", choices=ACCURACY, help="solver preset (default: the scene's)")
    p.add_argument("--out", metavar="DIR", help="write DIR/sweep.nc and DIR/map-*.png")
    p.add_argument("--no-maps", action="store_true", help="with --out: skip the figures")
    p.add_argument(
        "--chunk",
        type=int,
        default=DEFAULT_CHUNK,
        metavar="N",
        help=f"points per chunk, one compiled batch (default {DEFAULT_CHUNK})",
    )
    p.add_argument(
        "--workers", type=int, metavar="N", help="start a local Dask cluster of N processes"
    )
    p.add_argument(
        "--scheduler", metavar="ADDRESS", help="use the running Dask scheduler at ADDRESS"
    )
    p.add_argument("--resume", action="store_true", help="continue the unfinished sweep in --out")
    p.add_argument("--force", action="store_true", help="overwrite existing outputs in --out")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")
    return p


def _values(items):
    """argparse's list for ``nargs="+"``: one item may itself be START:STOP:N."""
    if items is None:
        return None
    if len(items) == 1:
        return items[0]
    out = []
    for item in items:
        out += parse_values(item, "value")
    return out


def _summary(ds) -> str:
    """Per afterload and bpm: steady points, SV range, the best-efficiency design."""
    lines = [
        "afterload    bpm  steady      SV ml     peak F N   best efficiency at (Omega, C)",
    ]
    coords = {d: tuple(np.asarray(ds[d]).tolist()) for d in ds.dims}
    for head, rate in _map_keys(coords):
        sel = {"bpm": rate} | ({} if head is None else {"afterload_mmHg": head})
        cut = ds[["stroke_volume_ml", "peak_force_N", "efficiency", "steady"]].sel(sel).load()
        sv, force = cut["stroke_volume_ml"].values, cut["peak_force_N"].values
        steady_mask = cut["steady"].values
        steady = int(steady_mask.sum())
        eff = cut["efficiency"].values
        note = ""
        if steady:
            eff = np.where(steady_mask, eff, np.nan)
        elif np.isfinite(eff).any():
            note = " (no point steady)"
        if np.isfinite(eff).any():
            i, j = np.unravel_index(np.nanargmax(eff), eff.shape)
            best = f"{eff[i, j]:.3f} at ({coords['omega'][i]:g}, {coords['shortening'][j]:g}){note}"
        else:
            best = "-"
        with np.errstate(all="ignore"):
            sv_range = f"{np.nanmin(sv):5.1f}-{np.nanmax(sv):5.1f}"
            f_range = f"{np.nanmin(force):5.1f}-{np.nanmax(force):5.1f}"
        if not np.isfinite(sv).any():
            sv_range = f_range = "-"
        head_txt = "-" if head is None else f"{head:g} mmHg"
        lines.append(
            f"{head_txt:>9}  {rate:5g}  {steady:6d}  {sv_range:>11}  {f_range:>11}   {best}"
        )
    return "\n".join(lines)


def main(argv=None) -> int:
    args = _parser().parse_args(argv)
    import jax

    jax.config.update("jax_enable_x64", True)
    import warnings

    from cardiosoft._cli import fail

    say = (lambda m: None) if args.quiet else (lambda m: print(m, file=sys.stderr))
    try:
        if args.workers is not None and args.workers < 1:
            raise ValueError(f"--workers {args.workers}: allowed a whole number >= 1")
        if args.workers is not None and args.scheduler is not None:
            raise ValueError("--workers and --scheduler: give one of them")
        if args.resume and not args.out:
            raise ValueError("--resume needs --out DIR, the folder of the unfinished sweep")
        if args.chunk < 1:
            raise ValueError(f"--chunk {args.chunk}: allowed a whole number of points >= 1")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # Dask's notes on ports and memory are not errors
            ds = design_sweep(
                args.scene,
                omega=args.omega,
                shortening=args.shortening,
                afterload=_values(args.afterload),
                bpm=_values(args.bpm),
                beats=args.beats,
                accuracy=args.accuracy,
                out=args.out,
                chunk=args.chunk,
                workers=args.workers,
                scheduler=args.scheduler,
                resume=args.resume,
                force=args.force,
                maps=not args.no_maps,
                progress=not args.quiet,
                log=say,
            )
    except (ValueError, FileNotFoundError) as err:
        return fail(err)
    except KeyboardInterrupt:
        where = (
            f"; rerun with --resume to continue ({Path(args.out) / PARTIAL})" if args.out else ""
        )
        print(f"interrupted{where}", file=sys.stderr)
        return 130
    if not args.quiet:
        print(_summary(ds))
        bad = int(ds["steady"].size - ds["steady"].sum())
        if bad:
            counts = np.bincount(np.asarray(ds["status"]).ravel(), minlength=len(STATUS))
            detail = ", ".join(
                f"{counts[k]} {STATUS[k]}" for k in range(1, len(STATUS)) if counts[k]
            )
            print(
                f"warning: {bad} of {ds['steady'].size} points not steady ({detail})",
                file=sys.stderr,
            )
    ds.close()
    return 0
