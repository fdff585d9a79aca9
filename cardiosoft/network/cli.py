"""``cardiosoft simulate --scene model.json``: an svZeroDSolver model, run as svZeroDSolver runs
it. Prints each node's mean pressure and flow over the last beat in the model's own units,
then each chamber's and vessel's record (:mod:`cardiosoft.network.block_metrics`; also
``summary.json``'s ``blocks``) and, with ``--out DIR``, writes ``traces.csv`` (``time`` and
one column per svZeroDSolver variable, under svZeroDSolver's names; with the model's
``output_derivative`` each one's ``ydot:NAME`` too, with ``output_mean_only`` one row of
means) and ``summary.json``.

``--pump-chamber NAME`` puts the soft pump in place of the model's chamber NAME
(:mod:`cardiosoft.network.pump_in_model`; ``--units`` the model's units, ``--omega``,
``--shortening`` and ``--pump`` its design and surrogate) and prints its beat; with
``--uncertainty`` every record's numbers get the 95 % band of the pump's posterior draws
(:func:`~cardiosoft.network.pump_uncertainty.pump_bands`).

``--verify`` reruns the model at the reference preset and reports each record's difference
from it (its numerical error estimate; ``summary.json``'s ``verification``).

``--steady`` runs beat after beat to the periodic steady state instead of the model's
``number_of_cardiac_cycles`` and reports the steady beat
(:func:`cardiosoft.network.run.simulate`'s ``steady``).

``--as-svzerod`` steps the model as svZeroDSolver steps it, its generalized-alpha scheme at
the model's own step, for svZeroDSolver's digits rather than the converged answer
(:func:`cardiosoft.network.gen_alpha.step_as_svzerod`).

Exit status: 0; 1 when the solve failed, its Newton did not converge or, with ``--steady``, the
steady state was not reached; 2 on bad input (a model or an option this reader does not take,
refused in one line).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

from cardiosoft.network.block_metrics import block_metrics, block_table, time_mean

OUTPUT_FILES = ("summary.json", "traces.csv")

_SCENE_ONLY = (
    ("omega", None),
    ("shortening", None),
    ("bpm", None),
    ("afterload", None),
    ("beats", None),
    ("max_steps", None),
    ("pump", None),
    ("add_effect", []),
    ("energy", False),
    ("compare_paper", False),
    ("uncertainty", False),
    ("explain", False),
)
"""Options of ``simulate`` that belong to the pump's scenes, with their defaults."""


_PUMP_OPTIONS = ("omega", "shortening", "pump", "uncertainty")
"""Options of the pump's scenes that also set the soft pump of ``--pump-chamber``."""


def _check_options(args) -> None:
    placing = getattr(args, "pump_chamber", None) is not None
    if getattr(args, "units", None) is not None and not placing:
        raise ValueError(
            "--units: only with --pump-chamber (a model alone is solved in its own units)"
        )
    for name, default in _SCENE_ONLY:
        if placing and name in _PUMP_OPTIONS:
            continue
        if name in _PUMP_OPTIONS and getattr(args, name, default) != default:
            raise ValueError(
                f"--{name}: with an svZeroDSolver model, only for the soft pump of "
                "--pump-chamber NAME"
            )
        if getattr(args, name, default) != default:
            raise ValueError(
                f"--{name.replace('_', '-')} does not apply to an svZeroDSolver model; "
                "its file sets the run"
            )
    if getattr(args, "as_svzerod", None):
        for flag, given in (
            ("--steady", getattr(args, "steady", None) is not None),
            ("--accuracy", getattr(args, "accuracy", None) is not None),
            ("--verify", getattr(args, "verify", False)),
            ("--pump-chamber", placing),
        ):
            if given:
                raise ValueError(
                    f"--as-svzerod: not with {flag} (the model is stepped as svZeroDSolver "
                    "steps it: its own cycles and step, its own blocks)"
                )
    if getattr(args, "steady", None) == "shooting":
        raise ValueError(
            "--steady shooting: an svZeroDSolver model reaches its periodic steady state beat "
            "after beat (--steady)"
        )


def simulate_model(args, console) -> int:
    """Run the model ``args.scene`` names; returns the exit status."""
    from cardiosoft.console import fail
    from cardiosoft.files import check_writable_folder, refuse_overwrite, write_together
    from cardiosoft.network import read, simulate
    from cardiosoft.network.pump_in_model import pump_flags, pump_metrics

    out_dir = Path(args.out) if args.out else None
    try:
        _check_options(args)
        if out_dir is not None:
            check_writable_folder(out_dir)
            for name in OUTPUT_FILES:
                refuse_overwrite(out_dir / name, args.force)
        placement = _placement(args)
        model = read(args.scene, pump=placement)
    except OSError as err:
        return fail(ValueError(f"--scene {args.scene}: {err.strerror or err}"))
    except ValueError as err:  # an unsupported model or option, a broken JSON file
        return fail(ValueError(f"--scene {args.scene}: {err}"))
    posterior = None
    if getattr(args, "uncertainty", False):  # its draws checked before anything runs
        from cardiosoft.posterior import first_draws
        from cardiosoft.pump import load_posterior

        try:
            posterior = first_draws(load_posterior(placement.surrogate), args.draws)
        except (OSError, ValueError) as err:
            return fail(ValueError(f"--uncertainty --draws {args.draws}: {err}"))
    sim, net = model.simulation, model.network
    steady = getattr(args, "steady", None) is not None
    beats = "beats to the periodic steady state" if steady else f"{sim.cycles} beats"
    console.say(
        f"{model.name} (svZeroDSolver model): {len(net.blocks)} blocks, {net.n_nodes} nodes, "
        f"{net.n_states} states; {beats} of {net.period:g} s; compiling, then solving ..."
    )
    start = time.perf_counter()
    if getattr(args, "as_svzerod", None):
        from cardiosoft.network.gen_alpha import step_as_svzerod
        from cardiosoft.network.simulation_parameters import UnsupportedModel

        try:
            traces = step_as_svzerod(model)
        except UnsupportedModel as err:
            return fail(ValueError(f"--scene {args.scene}: {err}"))
    else:
        traces = simulate(model, args.accuracy or "default", steady=steady)
    seconds = time.perf_counter() - start
    console.say(
        f"done in {seconds:.1f} s ({traces.steps} steps"
        + (", implicit solver)" if traces.stiff else ")")
    )
    if traces.steady_start is False:
        console.fail(model.name, "the steady start-up's Newton did not converge")
    if not traces.solved:
        console.fail(model.name, "the solve failed, or the nodes' Newton did not converge")
    if traces.steady is False:
        console.fail(
            model.name,
            f"not at the periodic steady state after {traces.beats} beats (the last beat's "
            f"change {traces.residual:.3g} times the steady tolerance)",
        )
    beat = traces.last_beat(sim.points_per_cycle)  # what the records describe
    placements = ((placement,) if placement is not None else ()) + model.pumps
    pumps = {p.chamber: pump_metrics(beat, p, net.nodes) for p in placements}
    pump = None if placement is None else pumps[placement.chamber]
    blocks = block_metrics(net, beat)
    for own in model.pumps:  # the file's own pumps: their records are their blocks'
        blocks[own.chamber] = {**blocks.get(own.chamber, {}), **pumps[own.chamber]}
    for name, record in pumps.items():
        for flag in pump_flags(record):
            console.flag(f"{model.name} {name}", flag)
    uncertainty = verification = None
    if posterior is not None:
        uncertainty = _bands(args, model, placement, posterior, steady, pump, blocks, console)
    if getattr(args, "verify", False):
        verification = _verification(args, model, placement, traces, steady, console)
    if not args.quiet:
        print(_table(model, beat))
        if blocks:
            print(block_table(blocks))
        for p in placements:
            record = pumps[p.chamber]
            where = f"in place of {p.chamber}" if p is placement else p.chamber
            print(
                f"soft pump {where} (Omega {p.omega:g}, C {p.shortening:g}), last beat: "
                f"EDV {record['edv_ml']:.1f} ml, ESV {record['esv_ml']:.1f} ml, "
                f"SV {record['stroke_volume_ml']:.1f} ml, EF {record['ejection_fraction']:.2f}, "
                f"peak cable force {record['peak_force_N']:.1f} N, cable work "
                f"{record['cable_work_J']:.3f} J, efficiency {_or_dash(record['efficiency'])}"
            )
    if out_dir is not None:
        summary = {
            "model": model.name,
            "units": "the model's own (svZeroDSolver files carry none)"
            if placement is None
            else f"{placement.units} (--units); pull:NAME in m and cable_force:NAME in N",
            "pump": None
            if placement is None
            else {
                "chamber": placement.chamber,
                "omega": placement.omega,
                "shortening": placement.shortening,
                "surrogate": placement.surrogate,
                **pump,
            },
            "blocks": blocks,
            "uncertainty": uncertainty,
            "verification": verification,
            "period": net.period,
            "beats": sim.cycles if traces.beats is None else traces.beats,
            "steady": traces.steady,
            "steady_residual": traces.residual,
            "accuracy": (
                f"stepped as svZeroDSolver steps it (generalized alpha, rho_infty "
                f"{sim.rho_infty:g}, {sim.steps_per_cycle} steps a beat)"
                if getattr(args, "as_svzerod", None)
                else args.accuracy or "default"
            ),
            "solved": traces.solved,
            "steady_start": traces.steady_start,
            "steps": traces.steps,
            "implicit_solver": traces.stiff,
            "seconds": seconds,
            **console.record(),
        }
        with write_together(out_dir) as staging:
            traces.write_csv(staging / "traces.csv")
            (staging / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
        for name in OUTPUT_FILES:
            console.say(f"wrote {out_dir / name}")
    return console.status()


def _bands(args, model, placement, posterior, steady, pump, blocks, console) -> dict:
    """``--uncertainty``: the ``posterior``'s draws (its first ``--draws``) of the pump in one
    call; each number of the pump's record and of every block's gets ``KEY_band`` (the 95 %
    range) and ``KEY_median``; failed draws flagged; prints the pump's. Returns
    ``summary.json``'s ``uncertainty`` entry."""
    from cardiosoft.network.closed_loop_tools import UNCERTAINTY
    from cardiosoft.network.pump_uncertainty import pump_bands

    console.say(f"uncertainty: {args.draws} posterior draws of the pump in one call ...")
    bands, failed, draws = pump_bands(
        model, placement, posterior, steady, args.accuracy or "default"
    )
    if failed:
        console.flag(
            model.name,
            f"{failed} of {draws} posterior draws failed or did not settle, and are left out "
            "of the bands",
        )
    for name, record in [(placement.chamber, pump), *blocks.items()]:
        for key, b in bands[name].items():
            if key in record and not key.endswith(("_band", "_median")):
                record[f"{key}_band"] = [b.low, b.high]
                record[f"{key}_median"] = b.median
    if not args.quiet:
        print(f"95 % bands over {draws - failed} posterior draws ({UNCERTAINTY}):")
        for key in ("stroke_volume_ml", "ejection_fraction", "peak_force_N", "efficiency"):
            b = bands[placement.chamber][key]
            print(f"  pump {key}: {_or_dash(pump[key])} in [{_or_dash(b.low)}, {_or_dash(b.high)}]")
    return {"draws": draws, "failed_draws": failed, "holds": UNCERTAINTY}


def _records(model, placement, traces) -> dict[str, dict]:
    """Every block's record of the last beat (the placed pump's joined to its chamber's)."""
    from cardiosoft.network.pump_in_model import placed_records

    if placement is not None:
        return placed_records(model, placement, traces)
    return block_metrics(model.network, traces.last_beat(model.simulation.points_per_cycle))


def _verification(args, model, placement, traces, steady, console) -> dict:
    """``--verify`` (calculation verification, as a scene's ``cardiosoft.verify``): the model
    run again at the "reference" preset (rtol 100 times tighter still if it ran there), each
    record's numbers' difference from the rerun (run - reference: the run's numerical error
    estimate); prints the largest. Returns ``summary.json``'s ``verification`` entry."""
    from cardiosoft.network import simulate
    from cardiosoft.solve import PRESETS

    accuracy = args.accuracy or "default"
    rtol = PRESETS["reference"]["rtol"] / (100.0 if accuracy == "reference" else 1.0)
    console.say(f"verifying: rerunning at the reference preset (rtol {rtol:g}) ...")
    start = time.perf_counter()
    rerun = simulate(model, "reference", rtol=rtol, steady=steady)
    seconds = time.perf_counter() - start
    if not rerun.solved:
        console.fail(model.name, "the verifying rerun at the reference preset failed")
    ran, reference = _records(model, placement, traces), _records(model, placement, rerun)
    out, worst = {}, (0.0, None)
    for block, record in ran.items():
        out[block] = {}
        for key, x in record.items():
            y = reference[block][key]
            if x is None or y is None:
                continue
            relative = abs(x - y) / abs(y) if y else None
            out[block][key] = {"run": x, "reference": y, "difference": x - y, "relative": relative}
            if relative is not None and relative > worst[0]:
                worst = (relative, f"{block}.{key}")
    if not args.quiet:
        print(
            "calculation verification (ASME V&V 40): the difference from a rerun at rtol "
            f"{rtol:g}: largest relative {worst[0]:.2e}" + (f" ({worst[1]})" if worst[1] else "")
        )
    return {
        "rerun_rtol": rtol,
        "rerun_seconds": seconds,
        "rerun_solved": rerun.solved,
        "largest_relative": worst[0],
        "largest_at": worst[1],
        "records": out,
    }


def _or_dash(value) -> str:
    return "-" if value is None else f"{value:.2f}"


def _placement(args):
    """The soft pump of ``--pump-chamber``, or None."""
    if getattr(args, "pump_chamber", None) is None:
        return None
    from cardiosoft.network.pump_in_model import DEFAULT_UNITS, PROTOTYPE, PumpPlacement

    omega = PROTOTYPE[0] if args.omega is None else args.omega
    shortening = PROTOTYPE[1] if args.shortening is None else args.shortening
    units = args.units or DEFAULT_UNITS
    return PumpPlacement(args.pump_chamber, units, omega, shortening, args.pump)


def _table(model, traces) -> str:
    """Each node's time mean pressure and flow over the reported time (the model's units)."""
    rows = [f"{'node':40s} {'mean pressure':>15s} {'mean flow':>15s}"]
    for up, down in model.network.nodes:
        p = time_mean(traces.values[f"pressure:{up}:{down}"], traces.time)
        q = time_mean(traces.values[f"flow:{up}:{down}"], traces.time)
        rows.append(f"{up + ':' + down:40s} {p:15.6g} {q:15.6g}")
    return "\n".join(rows)
