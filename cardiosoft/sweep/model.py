"""Design-space maps of the soft pump in a user's svZeroDSolver model (issue #40, "Tools").

    cardiosoft sweep --scene model.json --pump-chamber LV --units si \\
        --omega 2:6:8 --shortening 0.25:0.55:8 --out maps/

From Python (float64 on)::

    from cardiosoft.network.pump_in_model import PumpPlacement
    from cardiosoft.sweep.model import model_sweep
    ds = model_sweep("model.json", PumpPlacement("LV", "si"), omega="2:6:8",
                     shortening="0.25:0.55:8")
    ds["LV.stroke_volume_ml"].plot()

**What is computed.** Every point of the grid Omega x C is the model with the pump at that
design (:func:`~cardiosoft.network.pump_in_model.with_designs`), run beat after beat to its
periodic steady state (:func:`cardiosoft.network.run.simulate` with ``steady``, as ``simulate
--scene model.json --steady`` and ``design`` run it). Its variables are the records ``simulate``
prints, by ``BLOCK.KEY`` (:func:`cardiosoft.design.model.metric_values`): the pump's in ml, N,
J and mmHg, every other chamber's and vessel's in the model's own units.

**Chunks.** The grid is cut, in C order, into chunks of ``chunk`` points, the last padded with
its last point: one batched call each, one compiled program for every chunk. The network's
solve reports its flags (solved, steady) for a whole batch, so a point's ``steady`` and
``status`` are its chunk's. A chunk that fails marks its points and does not stop the sweep.
The open-loop sweep's Dask cluster, ``--resume`` and ``--uncertainty`` are not taken here.

**Output.** ``DIR/sweep.nc`` (NetCDF 4): dimensions ``omega``, ``shortening`` and ``bpm`` (the
model's one rate, so that the maps and the summary read it as they read a scene's); ``steady``,
``status`` (:data:`cardiosoft.sweep.chunk.STATUS`), ``flagged`` (the pump's pressure outside the
surrogate's fitted range, or a pushing cable) and ``beats``; the model, chamber, units and
surrogate as attributes. ``DIR/map-*.png``: the pump's stroke volume, ejection fraction and
peak force over Omega x C.
"""

from __future__ import annotations

import itertools
import json
import math
from pathlib import Path

import numpy as np

from cardiosoft.sweep.chunk import CHUNK_FAILED, NONFINITE, NOT_STEADY, OK, SOLVER_FAILED, STATUS
from cardiosoft.sweep.plan import DEFAULT_CHUNK, chunk_size, design_grid

__all__ = ["model_sweep"]

PUMP_UNITS = {"_ml": "ml", "_N": "N", "_J": "J", "_mmHg": "mmHg"}
"""A pump record's unit by its key's ending."""
RATIOS = ("ejection_fraction", "efficiency")
"""The records' dimensionless keys; every other key without a unit's ending is in the model's
units."""


def _panels(chamber: str) -> list:
    return [
        (f"{chamber}.stroke_volume_ml", "pump stroke volume [ml]", "viridis"),
        (f"{chamber}.ejection_fraction", "pump ejection fraction [-]", "magma"),
        (f"{chamber}.peak_force_N", "pump peak cable force [N]", "cividis"),
    ]


def _solve_chunk(model, placement, accuracy, designs, valid, names):
    """The metrics of ``designs`` (padded; ``valid`` are real) in one batched call, with each
    point's status (the batch's solved and steady, the point's own finiteness) and flags, and
    the beats run; never raises for a failed solve."""
    from cardiosoft.design.model import metric_values
    from cardiosoft.network import simulate
    from cardiosoft.network.pump_in_model import placed_records, pump_flags, with_designs

    values = {name: np.full(valid, np.nan) for name in names}
    flagged = np.zeros(valid, bool)
    try:
        variants = with_designs(model, placement, designs[:, 0], designs[:, 1])
        traces = simulate(model, accuracy, variants=variants, steady=True)
    except Exception as err:  # a failed chunk must not stop the sweep
        return values, flagged, CHUNK_FAILED, 0, f"{type(err).__name__}: {err}".splitlines()[0]
    for i in range(valid):
        with np.errstate(all="ignore"):
            records = placed_records(model, placement, traces.variant(i))
        for name, value in metric_values(records).items():
            values[name][i] = np.nan if value is None else value
        flagged[i] = bool(pump_flags(records[placement.chamber]))
    finite = np.all([np.isfinite(values[p[0]]) for p in _panels(placement.chamber)], axis=0)
    batch = OK if traces.steady else NOT_STEADY
    status = np.where(finite, batch, NONFINITE) if traces.solved else SOLVER_FAILED
    return values, flagged, status, int(traces.beats or 0), ""


def model_sweep(
    path,
    placement,
    *,
    omega,
    shortening,
    accuracy: str = "default",
    chunk: int = DEFAULT_CHUNK,
    out=None,
    force: bool = False,
    maps: bool = True,
    progress: bool = True,
    log=None,
):
    """Simulate the pump ``placement`` (:class:`~cardiosoft.network.pump_in_model.
    PumpPlacement`) in the svZeroDSolver model at ``path`` at every design of the grid
    ``omega`` x ``shortening`` (``"START:STOP:N"``, one number or a sequence) to its periodic
    steady state (module docstring). ``accuracy``: the solver preset; ``chunk``: points a
    batched call; ``out``: a folder for ``sweep.nc`` and the maps (``maps=False``: none);
    ``force``: overwrite them; ``progress``: a bar on stderr; ``log``: one-line messages.
    Returns the ``xarray.Dataset``. Bad input raises ``ValueError`` before anything is solved
    or written."""
    import xarray as xr

    from cardiosoft.design.model import metric_names
    from cardiosoft.files import atomic_path, refuse_overwrite
    from cardiosoft.network import read
    from cardiosoft.progress import bar as progress_bar
    from cardiosoft.pump import load_card
    from cardiosoft.scene import ACCURACY
    from cardiosoft.sweep.maps import map_name, plot_maps
    from cardiosoft.sweep.plan import version

    say = log or (lambda message: None)
    coords = design_grid(omega, shortening)
    if accuracy not in ACCURACY:
        raise ValueError(f"accuracy = {accuracy!r}: allowed {', '.join(ACCURACY)}")
    size = len(coords["omega"]) * len(coords["shortening"])
    chunk = chunk_size(chunk, size)
    model = read(path, pump=placement)
    names = metric_names(model, placement)
    period = float(model.network.period)
    out_dir = None if out is None else Path(out)
    if out_dir is not None:
        if out_dir.exists() and not out_dir.is_dir():
            raise ValueError(f"--out {out_dir} exists and is not a folder")
        refuse_overwrite(out_dir / "sweep.nc", force)
        if maps:
            refuse_overwrite(out_dir / map_name(None, 60.0 / period), force)
    designs = np.array(list(itertools.product(coords["omega"], coords["shortening"])), float)
    n_chunks = math.ceil(size / chunk)
    say(
        f"{model.name}: the soft pump in place of {placement.chamber}, {size} designs in "
        f"{n_chunks} chunk(s) of {chunk} (the first call compiles)"
    )
    values = {name: np.full(size, np.nan) for name in names}
    status = np.full(size, CHUNK_FAILED, np.int8)
    flagged = np.zeros(size, bool)
    beats = np.zeros(size, np.int32)
    failed = {}
    bar = progress_bar(size, desc="sweep", unit="point", enabled=progress)
    for k in range(n_chunks):
        start, stop = k * chunk, min((k + 1) * chunk, size)
        batch = designs[start:stop]
        batch = np.concatenate([batch, np.repeat(batch[-1:], chunk - len(batch), axis=0)])
        got, flags, state, n_beats, error = _solve_chunk(
            model, placement, accuracy, batch, stop - start, names
        )
        for name in names:
            values[name][start:stop] = got[name]
        status[start:stop], flagged[start:stop], beats[start:stop] = state, flags, n_beats
        if error:
            failed[k] = error
        bar.update(stop - start)
    bar.close()
    shape = (len(coords["omega"]), len(coords["shortening"]), 1)
    dims = ("omega", "shortening", "bpm")

    def variable(array, units, long_name):
        return xr.Variable(dims, array.reshape(shape), {"units": units, "long_name": long_name})

    def unit(name):
        block, key = name.split(".", 1)
        if block == placement.chamber and key.endswith(tuple(PUMP_UNITS)):
            return next(u for end, u in PUMP_UNITS.items() if key.endswith(end))
        return "1" if key in RATIOS else f"the model's ({placement.units})"

    data = {name: variable(values[name], unit(name), name) for name in names}
    data |= {
        "steady": variable(status == OK, "1", "reached the periodic steady state (its chunk)"),
        "status": variable(status, "1", "the point's chunk's outcome"),
        "flagged": variable(flagged, "1", "pump pressure outside the fitted range or a pushing "
                            "cable"),
        "beats": variable(beats, "1", "beats integrated (its chunk)"),
    }  # fmt: skip
    card = load_card(placement.surrogate)
    attrs = {
        "title": f"cardiosoft design-space sweep of the soft pump in model {model.name}",
        "scene": model.name,
        "scene_source": str(Path(path)),
        "pump_chamber": placement.chamber,
        "model_units": placement.units,
        "surrogate": card["name"],
        "surrogate_sha256": card["weights_sha256"],
        "cardiosoft_version": version(),
        "solver_preset": accuracy,
        "beats_mode": "steady",
        "max_beats": int(beats.max()),
        "chunk": chunk,
        "status_meanings": " ".join(STATUS),
        "map_panels": json.dumps(_panels(placement.chamber)),
    }
    if failed:
        attrs["failed_chunks"] = "; ".join(f"chunk {i}: {m}" for i, m in sorted(failed.items()))
    ds = xr.Dataset(
        data,
        coords={"omega": list(coords["omega"]), "shortening": list(coords["shortening"]),
                "bpm": [60.0 / period]},
        attrs=attrs,
    )  # fmt: skip
    if out_dir is not None:
        out_dir.mkdir(parents=True, exist_ok=True)
        with atomic_path(out_dir / "sweep.nc") as tmp:
            ds.to_netcdf(tmp, engine="h5netcdf")
        say(f"wrote {out_dir / 'sweep.nc'}")
        if maps:
            for written in plot_maps(ds, out_dir):
                say(f"wrote {written}")
    return ds
