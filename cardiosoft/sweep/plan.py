"""The plan of a sweep: the grid (the values of each swept variable), its chunks, the scene,
the beats and the surrogate, validated before anything is solved or written."""

from __future__ import annotations

import dataclasses
import json
import math
import os
import sys

import numpy as np

from cardiosoft._validate import parse_values
from cardiosoft.sweep.chunk import STATUS

__all__ = ["COORDS", "DEFAULT_CHUNK", "DIMS", "Plan", "make_plan", "surrogate_of", "version"]

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


@dataclasses.dataclass(frozen=True)
class Plan:
    """A validated sweep: the scene, the grid, the beats, the chunks and the surrogate."""

    scene: object  # a Scene or a LoopScene
    coords: dict  # dim -> tuple of values (user units), in DIMS order
    beats: int | None
    chunk: int
    pump: object  # None (shipped), a path, or a PumpSurrogate with numpy leaves
    surrogate: str
    surrogate_sha256: str
    precision: str
    draws: int | None = None  # posterior draws per point (uncertainty), or None

    @property
    def shape(self) -> tuple[int, ...]:
        return tuple(len(v) for v in self.coords.values())

    @property
    def size(self) -> int:
        return math.prod(self.shape)

    @property
    def n_chunks(self) -> int:
        return -(-self.size // self.chunk)

    @property
    def metric_variables(self) -> dict:
        """The sweep's metric variables, its scene's kind's
        (:data:`~cardiosoft.sweep.chunk.METRIC_VARIABLES` for an open loop)."""
        from cardiosoft.scene_tools import tools

        return tools(self.scene).sweep_variables(self.scene)

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
            "format": 2,  # 2: chunks hold "flagged"
            "scene": dataclasses.asdict(self.scene),
            "coords": {k: list(v) for k, v in self.coords.items()},
            "beats": self.beats,
            "chunk": self.chunk,
            "surrogate": self.surrogate,
            "surrogate_sha256": self.surrogate_sha256,
            "precision": self.precision,
            "cardiosoft_version": version(),
            "uncertainty_draws": self.draws,
        }

    def attrs(self) -> dict:
        """The Dataset's attributes."""
        from cardiosoft.scene_tools import tools
        from cardiosoft.solve import solver_name

        scene = self.scene
        config = tools(scene).preset(scene)
        solver = solver_name(config)
        return {
            "title": f"cardiosoft design-space sweep of scene {scene.name}",
            "scene": scene.name,
            "scene_source": str(scene.source),
            "scene_description": scene.description,
            "scene_parameters": json.dumps(dataclasses.asdict(scene)),  # SI, as Scene holds it
            "surrogate": self.surrogate,
            "surrogate_sha256": self.surrogate_sha256,
            "cardiosoft_version": version(),
            "solver_preset": scene.accuracy,
            "solver": f"{solver}, rtol {float(config.rtol):g}, atol {float(config.atol):g}, "
            f"max_steps {config.max_steps}",
            "beats_mode": "steady" if self.beats is None else "fixed",
            "max_beats": scene.max_beats if self.beats is None else self.beats,
            "steady_tol": scene.steady_tol,
            "precision": self.precision,
            "chunk": self.chunk,
            "status_meanings": " ".join(STATUS),
            "map_panels": json.dumps(tools(scene).sweep_panels(scene)),
        } | self._uncertainty_attrs()

    def _uncertainty_attrs(self) -> dict:
        if self.draws is None:
            return {}
        from cardiosoft.pump import load_posterior

        card = load_posterior().card
        return {
            "uncertainty_draws": self.draws,
            "uncertainty": "<metric>_band_low/_high: the 95 % predictive band (the posterior's "
            f"first {self.draws} draws, each solved at the point, plus the model discrepancy; "
            "cardiosoft.posterior); band_failed_draws: draws left out of a point's bands",
            "posterior": card["file"],
            "posterior_sha256": card["sha256"],
        }


def version() -> str:
    """The version of the cardiosoft that runs the sweep."""
    return sys.modules["cardiosoft"].__version__  # the package is imported before this module


def make_plan(
    scene, omega, shortening, afterload, bpm, beats, accuracy, chunk, pump, precision,
    draws=None,
) -> Plan:
    from cardiosoft._validate import check_range
    from cardiosoft.experiment import configure
    from cardiosoft.pump import DEFAULT_ARTIFACT
    from cardiosoft.scene import RANGES
    from cardiosoft.scene_tools import check_supported, tools

    scene = configure(scene, accuracy=accuracy)
    if scene.static:
        raise ValueError(
            f"scene {scene.name} is static (no beats to simulate): sweep a dynamic scene "
            "such as bench-dynamic"
        )
    coords = design_grid(omega, shortening)
    # a scene without a pump to design (the native heart) says so now, not in every chunk
    tools(scene).configure(scene, omega=coords["omega"][0], shortening=coords["shortening"][0])
    given = None if afterload is None else parse_values(afterload, "afterload")
    heads = tools(scene).column_heads(scene, given, "sweep")
    if heads is not None:
        coords["afterload_mmHg"] = heads
    coords["bpm"] = (scene.bpm,) if bpm is None else parse_values(bpm, "bpm")
    check_range("bpm", coords["bpm"], "bpm", *RANGES["bpm"], lo_open=True)
    if beats is not None:
        if isinstance(beats, bool) or not isinstance(beats, int | np.integer):
            raise ValueError(f"beats = {beats!r}: allowed a whole number in [1, 500]")
        check_range("beats", beats, "beats", 1, 500)
        beats = int(beats)
    chunk = chunk_size(chunk, math.prod(len(v) for v in coords.values()))
    if pump is None and scene.pump != DEFAULT_ARTIFACT:
        pump = scene.pump  # the scene's own surrogate (its key 'pump')
    pump, name, digest = surrogate_of(pump)
    if draws is not None:
        from cardiosoft.pump import load_posterior

        check_supported(scene, "uncertainty", "uncertainty")
        check_supported(scene, "bench_bands", "uncertainty")  # band_result: ensemble_run
        if pump is not None:
            raise ValueError(
                "uncertainty: the posterior belongs to the shipped surrogate; sweep it "
                "(pump=None) or compute one for yours (python -m fit.posterior --artifact)"
            )
        total = load_posterior().card["draws"]
        if isinstance(draws, bool) or not isinstance(draws, int | np.integer) or not (
            2 <= draws <= total
        ):
            raise ValueError(f"draws = {draws!r}: allowed 2 to {total} (the posterior's draws)")
        draws = int(draws)
    return Plan(scene, coords, beats, chunk, pump, name, digest, precision, draws)


def design_grid(omega, shortening) -> dict:
    """The swept designs ``{"omega": values, "shortening": values}`` from their forms
    (:func:`~cardiosoft._validate.parse_values`), checked against the design range."""
    from cardiosoft._validate import check_range
    from cardiosoft.scene import RANGES

    coords = {
        "omega": parse_values(omega, "omega"),
        "shortening": parse_values(shortening, "shortening"),
    }
    check_range("omega", coords["omega"], "", *RANGES["omega"])
    check_range("shortening C", coords["shortening"], "", *RANGES["shortening"])
    return coords


def chunk_size(chunk, size: int) -> int:
    """The points a chunk holds: ``chunk``, checked, and no more than the grid's ``size`` (a
    small grid is one chunk of its own size)."""
    if isinstance(chunk, bool) or not isinstance(chunk, int | np.integer) or chunk < 1:
        raise ValueError(f"chunk = {chunk!r}: allowed a whole number of points >= 1")
    return int(min(chunk, size))


def surrogate_of(pump):
    """(what a task carries, name, sha256) of the shipped surrogate, a path or an object."""
    from cardiosoft import pump as pump_module

    if pump is None or isinstance(pump, str | os.PathLike):
        card = pump_module.load_card(pump)
        if pump is not None:
            pump_module.load(pump)  # checks the file and its hash now, not on a worker
            pump = str(pump_module.artifact_path(pump).resolve())
        return pump, card["name"], card["weights_sha256"]
    if not isinstance(pump, pump_module.PumpSurrogate):
        raise ValueError(f"pump = {pump!r}: allowed None, a surrogate file or a PumpSurrogate")
    import hashlib

    import jax

    leaves = [np.asarray(leaf) for leaf in jax.tree_util.tree_leaves(pump)]
    digest = hashlib.sha256(b"".join(leaf.tobytes() for leaf in leaves)).hexdigest()
    # numpy leaves travel to a worker unchanged; JAX arrays would arrive in its precision
    return jax.tree_util.tree_map(np.asarray, pump), "in-memory PumpSurrogate", digest
