"""The sweep itself: :func:`design_sweep` plans the grid, runs its chunks where asked, keeps each
finished chunk (in memory, or on disk for resume) and assembles the Dataset and the maps."""

from __future__ import annotations

import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

from cardiosoft import progress as progress_output
from cardiosoft.sweep.chunk import Task
from cardiosoft.sweep.executor import executor
from cardiosoft.sweep.maps import map_keys, map_name, plot_maps
from cardiosoft.sweep.plan import DEFAULT_CHUNK, Plan, make_plan
from cardiosoft.sweep.store import OUTPUT, PARTIAL, PartialSweep, write_netcdf

__all__ = ["design_sweep"]


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
    uncertainty: int | None = None,
    log=None,
):
    """Simulate every point of a grid of designs, afterloads and rates; metrics only.

    **Arguments** (user units; :mod:`cardiosoft.sweep` says what happens):

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
    - ``progress``: a progress bar on stderr (on a terminal); ``pump``: a surrogate file or
      :class:`~cardiosoft.pump.PumpSurrogate` (default the shipped one); ``log``: a function
      that gets one-line messages (default: none).
    - ``uncertainty``: solve the shipped surrogate's first N posterior draws at every point
      too (one batch per chunk, N times its points) and add each metric's 95 % predictive
      band as ``<metric>_band_low`` and ``<metric>_band_high``
      (:data:`cardiosoft.sweep.chunk.BAND_VARIABLES`).

    **Returns:** the ``xarray.Dataset`` (:mod:`cardiosoft.sweep`); with ``out``, opened lazily
    from ``out/sweep.nc``. Bad input raises ``ValueError`` before anything is written or solved.
    """
    import jax

    say = log or (lambda message: None)
    _check_places(workers, scheduler, client)
    precision = "float64" if jax.config.jax_enable_x64 else "float32"
    plan = make_plan(
        scene, omega, shortening, afterload, bpm, beats, accuracy, chunk, pump, precision,
        uncertainty,
    )
    out_dir = None if out is None else Path(out)
    partial, done = _open_store(plan, out_dir, maps, resume, force)
    with executor(workers, scheduler, client) as (run, where):
        if partial is not None and (not resume or not partial.exists()):
            if partial.folder.exists():
                shutil.rmtree(partial.folder)
            partial.start(plan.identity())
        kept = _solve(plan, run, where, partial, done, progress, say)
    results = (partial.load(i) if partial is not None else kept[i] for i in range(plan.n_chunks))
    failed = {i: r["error"].item() for i, r in enumerate(results) if r["error"].item()}
    return _assemble(plan, out_dir, partial, kept, failed, maps, say)


def _check_places(workers, scheduler, client) -> None:
    if workers is not None and (
        isinstance(workers, bool) or not isinstance(workers, int | np.integer) or workers < 1
    ):
        raise ValueError(f"workers = {workers!r}: allowed a whole number >= 1")
    if sum(x is not None for x in (workers, scheduler, client)) > 1:
        raise ValueError("give at most one of workers, scheduler and client")


def _open_store(plan: Plan, out_dir, maps, resume, force):
    """(the unfinished sweep's store or None, the chunks it holds already); refuses to
    overwrite an output or an unfinished sweep unless asked."""
    from cardiosoft.files import refuse_overwrite

    if out_dir is None:
        if resume:
            raise ValueError("resume needs an output folder (out) holding the unfinished sweep")
        return None, set()
    if out_dir.exists() and not out_dir.is_dir():
        raise ValueError(f"out {out_dir} exists and is not a folder")
    names = [OUTPUT] + ([map_name(*k) for k in map_keys(plan.coords)] if maps else [])
    for name in names:
        refuse_overwrite(out_dir / name, force)
    partial = PartialSweep(out_dir / PARTIAL)
    done: set[int] = set()
    if partial.exists():
        if resume:
            partial.check(plan.identity())
            done = partial.done() & set(range(plan.n_chunks))
        elif not force:
            raise ValueError(
                f"{out_dir} holds an unfinished sweep ({PARTIAL}/): pass --resume to "
                "continue it or --force to start over"
            )
    return partial, done


def _solve(plan: Plan, run, where: str, partial, done: set[int], progress: bool, say) -> dict:
    """Run the chunks not ``done``; each result saved to ``partial`` (or kept, returned)."""
    todo = [i for i in range(plan.n_chunks) if i not in done]
    say(
        f"{plan.scene.name}: {plan.size} points ({' x '.join(map(str, plan.shape))} "
        f"{' x '.join(plan.coords)}) in {plan.n_chunks} chunks of {plan.chunk}"
        + (f", {len(done)} done already" if done else "")
        + f"; solving in {where} ..."
    )
    kept: dict[int, dict] = {}
    x64 = plan.precision == "float64"

    def tasks():
        for i in todo:
            members, valid = plan.members(i)
            yield Task(i, plan.scene, members, valid, plan.beats, plan.pump, x64, plan.draws)

    start = time.perf_counter()
    beats_run = 0
    points = sum(_chunk_len(plan, i) for i in todo)
    bar = progress_output.bar(
        plan.size, desc="points", unit="pt", enabled=progress, initial=plan.size - points
    )
    with bar:
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
            f"solved {points} points in {elapsed:.1f} s "
            f"({beats_run / max(elapsed, 1e-9):,.0f} beats/s)"
        )
    return kept


def _assemble(plan: Plan, out_dir, partial, kept: dict, failed: dict, maps: bool, say):
    """The Dataset from every chunk: in memory, or written with its maps into ``out_dir``
    (all files staged, then moved into place; the unfinished sweep's folder removed)."""
    import xarray as xr

    def chunks():
        for i in range(plan.n_chunks):
            yield i, (partial.load(i) if partial is not None else kept[i])

    if out_dir is None:
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / OUTPUT
            write_netcdf(plan, chunks(), path, failed)
            return xr.load_dataset(path, engine="h5netcdf")
    staging = Path(tempfile.mkdtemp(dir=out_dir, prefix=".staging-"))
    try:
        write_netcdf(plan, chunks(), staging / OUTPUT, failed)
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


def _chunk_len(plan: Plan, index: int) -> int:
    return min(plan.chunk, plan.size - index * plan.chunk)
