"""The files of a sweep: the finished chunks of an unfinished sweep (resume), and the Dataset
written to NetCDF chunk by chunk. Every file is written whole (a temporary file renamed into
place) or not at all."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from cardiosoft.sweep.chunk import BAND_VARIABLES, SOLVER_VARIABLES, STATUS
from cardiosoft.sweep.plan import COORDS, Plan

__all__ = ["OUTPUT", "PARTIAL", "PartialSweep", "flat_range_boxes", "write_netcdf"]

OUTPUT = "sweep.nc"
"""The Dataset's file in the output folder."""
PARTIAL = "sweep.partial"
"""Folder of the finished chunks of a sweep that is not done yet (removed when it is)."""


def flat_range_boxes(start: int, stop: int, shape) -> list[tuple[slice, ...]]:
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
        return [(slice(i0, i0 + 1), *b) for b in flat_range_boxes(r0, r1, shape[1:])]
    out = []
    if r0:
        out += [(slice(i0, i0 + 1), *b) for b in flat_range_boxes(r0, inner, shape[1:])]
        i0 += 1
    if i1 > i0:
        out.append((slice(i0, i1), *(slice(0, n) for n in shape[1:])))
    if r1:
        out += [(slice(i1, i1 + 1), *b) for b in flat_range_boxes(0, r1, shape[1:])]
    return out


class PartialSweep:
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


def write_netcdf(plan: Plan, chunks, path: Path, failed: dict) -> None:
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
        for name, (_, _, units, long_name) in plan.metric_variables.items():
            variables[name] = f.create_variable(name, dims, dtype="f8", fillvalue=np.nan)
            variables[name].attrs.update(units=units, long_name=long_name)
        for name, (dtype, units, long_name) in SOLVER_VARIABLES.items():
            if dtype == "f8":
                var = f.create_variable(name, dims, dtype="f8", fillvalue=np.nan)
            else:
                var = f.create_variable(name, dims, dtype="i1" if dtype == "bool" else dtype)
            var.attrs.update(units=units, long_name=long_name)
            if dtype == "bool":
                var.attrs["dtype"] = "bool"  # xarray's encoding of a bool variable
            variables[name] = var
        if plan.draws is not None:
            for name in BAND_VARIABLES:
                _, _, units, long_name = plan.metric_variables[name]
                for edge, which in (("low", "lower"), ("high", "upper")):
                    var = f.create_variable(f"{name}_band_{edge}", dims, dtype="f8",
                                            fillvalue=np.nan)
                    var.attrs.update(units=units, long_name=f"{which} edge of the 95 % "
                                     f"predictive band of: {long_name}")
                    variables[f"{name}_band_{edge}"] = var
            var = f.create_variable("band_failed_draws", dims, dtype="i4")
            var.attrs.update(units="1", long_name="posterior draws that failed or missed the "
                             "steady state at the point, left out of its bands")
            variables["band_failed_draws"] = var
        variables["status"].attrs["flag_values"] = np.arange(len(STATUS), dtype=np.int8)
        variables["status"].attrs["flag_meanings"] = " ".join(STATUS)
        f.attrs.update(attrs)
        for index, result in chunks:
            start = index * plan.chunk
            offset = 0
            for box in flat_range_boxes(start, start + len(result["status"]), plan.shape):
                shape = tuple(s.stop - s.start for s in box)
                n = math.prod(shape)
                for name, var in variables.items():
                    values = result[name][offset : offset + n].reshape(shape)
                    var[box] = values.astype(np.int8) if values.dtype == bool else values
                offset += n
