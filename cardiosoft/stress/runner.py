"""Running the hard cases: each batch through the public batch solve (a closed loop's through
:func:`~cardiosoft.network.loop_batch.solve_loop`), its first design also through the command line
(group ``cli``), each member checked (:mod:`cardiosoft.stress.checks`)."""

from __future__ import annotations

import contextlib
import dataclasses
import inspect
import io
import json
import math
import tempfile
import threading
from pathlib import Path

import numpy as np

from cardiosoft.batch import solve_beats, solve_static
from cardiosoft.metrics import BeatMetrics
from cardiosoft.network.loop_batch import solve_loop
from cardiosoft.network.loop_results import loop_member_results, pump_sides
from cardiosoft.results import RunResult, member_results, summary_records
from cardiosoft.scene import Scene
from cardiosoft.static import column_stiffness
from cardiosoft.stress.cases import Batch, Case, member_id
from cardiosoft.stress.checks import (
    LoopView,
    MemberView,
    Outcome,
    check_loop_member,
    check_member,
    left_half_capacity,
    outcome,
)
from cardiosoft.stress.loop_cases import LoopBatch
from cardiosoft.stress.model_cases import ModelBatch, balance_allowance, check_model_member
from cardiosoft.units import RHO_WATER, G, mmHg

__all__ = [
    "CLI_RTOL",
    "Runner",
    "cli_has",
    "differences",
    "energy_available",
    "raw_metrics",
    "static_pressures",
    "static_raw",
]

CLI_RTOL = 1e-12
"""The CLI and the API run the same compiled solve: their numbers agree to round-off."""


def energy_available() -> bool:
    """Whether the installed library keeps the energy account (``solve_beats(energy=True)``)."""
    fields = {f.name for f in dataclasses.fields(BeatMetrics)}
    return "energy" in inspect.signature(solve_beats).parameters and "energy_residual" in fields


def raw_metrics(sol, i: int) -> dict[str, float]:
    out = {}
    for f in dataclasses.fields(BeatMetrics):
        value = getattr(sol.metrics, f.name)
        if value is not None:
            out[f.name] = float(value[i])
    return out


def static_raw(static, i: int) -> dict[str, float]:
    return {
        "static_stroke_volume": float(static.stroke_volume[i]),
        "static_peak_force": float(static.peak_force[i]),
        "static_mech_work": float(static.mech_work[i]),
        "static_efficiency": float(static.efficiency[i]),
    }


def static_pressures(scene: Scene, static, heads_mmHg) -> list[float]:
    """Largest pressure of each quasi-static stroke (mmHg): head plus the column's rise."""
    area = 0.25 * math.pi * scene.column_diameter**2
    k = float(column_stiffness(area, RHO_WATER, G)) if scene.has("column_rise") else 0.0
    sv = np.asarray(static.stroke_volume)
    return [h + k * max(float(s), 0.0) / mmHg for h, s in zip(heads_mmHg, sv, strict=True)]


class Runner:
    """Runs batches; keeps the quasi-static strokes of a design set (rate-independent)."""

    def __init__(self, energy: bool):
        from cardiosoft.pump import load

        self.pump = load()
        self.domain = self.pump.domain
        self.energy = energy
        self.cli_energy = energy and cli_has("--energy")
        self._static: dict = {}
        self._lock = threading.Lock()

    def static(self, batch: Batch, scene: Scene):
        with self._lock:  # the command-line check may run beside the suite, on a thread
            return self._static_locked(batch, scene)

    def _static_locked(self, batch: Batch, scene: Scene):
        key = (
            batch.scene,
            tuple((k, v) for k, v in batch.changes if k != "accuracy"),
            batch.omega,
            batch.shortening,
            batch.afterload_mmHg,
        )
        if key not in self._static:
            self._static[key] = solve_static(
                scene,
                omega=np.asarray(batch.omega),
                shortening=np.asarray(batch.shortening),
                afterload=np.asarray(batch.afterload_mmHg) * mmHg,
                pump=self.pump,
            )
        return self._static[key]

    def run(self, batch: Batch | LoopBatch | ModelBatch) -> list[Outcome]:
        if isinstance(batch, LoopBatch):
            return self.run_loop(batch)
        if isinstance(batch, ModelBatch):
            return self.run_model(batch)
        cases = batch.cases()
        try:
            scene = batch.build_scene()
            labels = [c.id for c in cases]
            static = self.static(batch, scene) if scene.afterload.has_heads else None
            if scene.static:
                records = member_results(labels, None, static, self.domain)
                sol = None
            else:
                kwargs = {"energy": True} if self.energy else {}
                sol = solve_beats(
                    scene,
                    omega=np.asarray(batch.omega),
                    shortening=np.asarray(batch.shortening),
                    bpm=np.asarray(batch.bpm),
                    afterload=(
                        None
                        if batch.afterload_mmHg is None
                        else np.asarray(batch.afterload_mmHg) * mmHg
                    ),
                    beats=batch.beats,
                    save="metrics",
                    steady=batch.steady,
                    pump=self.pump,
                    **kwargs,
                )
                records = member_results(labels, sol, static, self.domain)
            pressures = (
                static_pressures(scene, static, batch.afterload_mmHg)
                if static is not None
                else [None] * len(cases)
            )
        except Exception as err:  # a batch that cannot run fails each of its cases, visibly
            text = f"{type(err).__name__}: {err}".splitlines()[0][:300]
            return [outcome(c, [("exception", text)], []) for c in cases]
        out = []
        for i, case in enumerate(cases):
            raw = {} if sol is None else raw_metrics(sol, i)
            if static is not None:
                raw |= static_raw(static, i)
            view = MemberView(
                raw=raw,
                record=records[i],
                succeeded=True if sol is None else bool(sol.succeeded[i]),
                steady=True if sol is None else bool(sol.steady[i]),
                static_pressure_mmHg=pressures[i],
                accuracy=scene.accuracy,
            )
            out.append(outcome(case, *check_member(view, self.domain)))
        return out

    def run_model(self, batch: ModelBatch) -> list[Outcome]:
        """The pump's designs in a model, one batched call of the network's solve to the
        periodic steady state (:mod:`cardiosoft.stress.model_cases`)."""
        from cardiosoft.network import read, simulate
        from cardiosoft.network.export import to_svzerod
        from cardiosoft.network.pump_in_model import (
            PumpPlacement,
            placed_records,
            pump_beat,
            pump_flags,
            with_designs,
        )
        cases = batch.cases()
        try:
            config = to_svzerod(batch.build_scene(), units="mmHg", beats=3)
            placement = PumpPlacement(batch.chamber, "mmHg")
            model = read(config, pump=placement)
            omegas, shortenings = zip(*batch.designs, strict=True)
            variants = with_designs(model, placement, omegas, shortenings)
            traces = simulate(model, variants=variants, steady=True)
        except Exception as err:  # a batch that cannot run fails each of its cases, visibly
            text = f"{type(err).__name__}: {err}".splitlines()[0][:300]
            return [outcome(c, [("exception", text)], []) for c in cases]
        out, name = [], batch.chamber
        for i, case in enumerate(cases):
            one = traces.variant(i)
            with np.errstate(all="ignore"):
                records = placed_records(model, placement, one)
            beat = one.last_beat(model.simulation.points_per_cycle)
            allowance = balance_allowance(*pump_beat(beat, placement, model.network.nodes))
            flags = pump_flags(records[name])
            problems = check_model_member(
                records, name, traces.solved, bool(traces.steady), flags, allowance
            )
            out.append(outcome(case, problems, flags))
        return out

    def run_loop(self, batch: LoopBatch) -> list[Outcome]:
        """A closed loop's batch through :func:`~cardiosoft.network.loop_batch.solve_loop`, its
        records (the loop's flags) through
        :func:`~cardiosoft.network.loop_results.loop_member_results`."""
        cases = batch.cases()
        try:
            scene = batch.build_scene()
            members = {k: np.asarray(v) for k, v in batch.members().items()}
            pump = self.pump if scene.pumps else None
            sol = solve_loop(scene, members=members, save="metrics", pump=pump)
            records = loop_member_results(scene, [c.id for c in cases], sol, self.domain)
        except Exception as err:  # a batch that cannot run fails each of its cases, visibly
            text = f"{type(err).__name__}: {err}".splitlines()[0][:300]
            return [outcome(c, [("exception", text)], []) for c in cases]
        sides = pump_sides(scene)
        out = []
        for i, case in enumerate(cases):
            member = MemberView(
                raw=dict(records[i].metrics),  # loop records keep the metrics as solved
                record=records[i],
                succeeded=bool(sol.succeeded[i]),
                steady=bool(sol.steady[i]),
                accuracy=scene.accuracy,
            )
            view = LoopView(member, sides, 60.0 / case.bpm, left_half_capacity(scene))
            out.append(outcome(case, *check_loop_member(view, self.domain)))
        return out

    def cli(self, batch: Batch) -> list[Outcome]:
        """The batch's first design through ``python -m cardiosoft.simulate`` and the API."""
        from cardiosoft import simulate

        scene = batch.build_scene()
        omega, c = batch.omega[0], batch.shortening[0]
        heads = (
            [
                h
                for o, s, h in zip(batch.omega, batch.shortening, batch.afterload_mmHg, strict=True)
                if (o, s) == (omega, c)
            ]
            if batch.afterload_mmHg is not None
            else None
        )
        bpm = None if batch.bpm is None else batch.bpm[0]
        prefix = batch.ids[0].split("/Omega=")[0].replace("grid/", "cli/", 1)
        ids = [member_id(prefix, omega, c, h) for h in (heads or [None])]
        cases = [
            Case(i, "cli", batch.scene, batch.changes, omega, c, bpm, h)
            for i, h in zip(ids, heads or [None], strict=True)
        ]
        argv = ["--scene", batch.scene, "--omega", repr(omega), "--shortening", repr(c)]
        if bpm is not None:
            argv += ["--bpm", repr(bpm), "--accuracy", scene.accuracy]
            argv += ["--energy"] if self.cli_energy else []
        if heads is not None:
            argv += ["--afterload", *map(repr, heads)]
        try:
            with tempfile.TemporaryDirectory() as tmp:
                # --quiet: nothing on stdout (this may run beside the suite's own progress)
                argv += ["--out", tmp, "--no-plot", "--force", "--quiet"]
                rc = simulate.main(argv)
                summary = Path(tmp) / "summary.json"
                if not summary.exists():
                    raise RuntimeError(f"exit status {rc} and no summary.json")
                written = json.loads(summary.read_text())
                cli_records, cli_flags = written["records"], written["flags"]
            api = self._api_records(scene, omega, c, bpm, heads)
        except Exception as error:
            text = f"{type(error).__name__}: {error}".splitlines()[0][:300]
            return [outcome(case, [("cli", text)], []) for case in cases]
        # exit status 1 when a member is not ok (solved and steady, as asked), else 0: flags
        # are warnings (DESIGN.md section 4), listed in summary.json as "<label>: <flag>"
        ok = all(r["ok"] for r in api)
        flagged = sorted(f.split(": ", 1)[1] for f in cli_flags)
        outcomes = []
        for case, a, b in zip(cases, api, cli_records, strict=True):
            problems = [("cli", d) for d in differences(a, b)]
            if rc != (0 if ok else 1):
                problems.append(
                    (
                        "cli",
                        f"exit status {rc}, but the API's records are "
                        f"{'all' if ok else 'not all'} ok",
                    )
                )
            if flagged != sorted(f for r in api for f in r["flags"]):
                problems.append(("cli", f"summary.json's flags {flagged} are not the API's"))
            outcomes.append(outcome(case, problems, []))
        return outcomes

    def _api_records(self, scene: Scene, omega, c, bpm, heads) -> list[dict]:
        """The same members through the API: ``solve_beats``/``solve_static`` with SI values."""
        n = len(heads or [None])
        members = {"omega": np.full(n, omega), "shortening": np.full(n, c)}
        if heads is not None:
            members["afterload"] = np.asarray(heads) * mmHg
        static = solve_static(scene, **members, pump=self.pump) if heads is not None else None
        labels = [f"{h:g} mmHg" for h in heads] if heads is not None else [scene.name]
        if scene.static:
            records = member_results(labels, None, static, self.domain)
        else:
            energy = {"energy": True} if self.cli_energy else {}
            sol = solve_beats(scene, **members, bpm=bpm, save="traces", pump=self.pump, **energy)
            records = member_results(labels, sol, static, self.domain)
        return summary_records(RunResult(scene, records))


def cli_has(option: str) -> bool:
    """Whether ``python -m cardiosoft.simulate`` takes ``option`` (its ``--help`` lists it)."""
    from cardiosoft import simulate

    with contextlib.redirect_stdout(io.StringIO()) as out, contextlib.suppress(SystemExit):
        simulate.main(["--help"])
    return option in out.getvalue()


def differences(api: dict, cli: dict) -> list[str]:
    """Where a CLI summary record differs from the API's (the label aside)."""
    out = []
    for key in sorted(set(api) | set(cli)):
        if key == "label":
            continue
        a, b = api.get(key), cli.get(key)
        if isinstance(a, float) and isinstance(b, int | float) and not isinstance(b, bool):
            if abs(a - b) <= CLI_RTOL * max(abs(a), abs(b)):
                continue
        elif a == b:
            continue
        out.append(f"{key}: API {a!r}, CLI {b!r}")
    return out
