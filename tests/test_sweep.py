"""Design-space sweeps (``cardiosoft.sweep``): labelled output, chunks that fail, resume, Dask,
and agreement with ``python -m cardiosoft.simulate``.

Every solve in this process uses one chunk size (3 points, so that a grid of 4 or 8 points has
a padded last chunk) and 2 beats: one compiled batch serves them all. The command-line runs are
subprocesses launched together by module fixtures, so that their start-ups overlap.
"""

from __future__ import annotations

import importlib
import json
import math
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest
import xarray as xr
from hypothesis import given, settings
from hypothesis import strategies as st

import cardiosoft
from cardiosoft.sweep import (
    CHUNK_FAILED,
    OUTPUT,
    PARTIAL,
    STATUS,
    VARIABLES,
    design_sweep,
    flat_range_boxes,
    map_name,
    parse_values,
)

sweep_module = importlib.import_module("cardiosoft.sweep")
chunk_module = importlib.import_module("cardiosoft.sweep.chunk")
REPO = Path(__file__).resolve().parent.parent
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
CHUNK, BEATS = 3, 2
GRID = dict(omega="3:4:2", shortening="0.3:0.4:2", afterload=60, bpm=[30, 60])
"""8 points in 3 chunks of 3, the last one padded."""
KW = dict(GRID, beats=BEATS, chunk=CHUNK, progress=False)
CLI_GRID = ["--omega", "3.5:4:2", "--shortening", "0.4", "--afterload", "60", "--bpm", "60"]
CLI_POINT = dict(omega=4.0, shortening=0.4, afterload_mmHg=60.0, bpm=60.0)
PAIRS = {
    "stroke_volume_ml": "dynamic_sv_ml",
    "ejection_fraction": "ef",
    "peak_force_N": "peak_force_N",
    "mech_work_J": "mech_work_J",
    "efficiency": "efficiency",
    "edv_ml": "edv_ml",
    "esv_ml": "esv_ml",
}
"""The Dataset's variables and the summary record's keys of the same metrics."""


def launch(module, *args):
    return subprocess.Popen(
        [sys.executable, "-m", module, *map(str, args)],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def finish(proc, timeout=600):
    out, err = proc.communicate(timeout=timeout)
    return subprocess.CompletedProcess(proc.args, proc.returncode, out, err)


BAD_INPUTS = {
    "empty range": ["--omega", "3:3:4", "--shortening", "0.4"],
    "N < 1": ["--omega", "1:5:0", "--shortening", "0.4"],
    "not a range": ["--omega", "1:5", "--shortening", "0.4"],
    "unknown scene": ["--scene", "nope", "--omega", "4", "--shortening", "0.4"],
    "out of range": ["--omega", "4", "--shortening", "0.2:0.9:3"],
    "chunk": ["--omega", "4", "--shortening", "0.4", "--chunk", "0"],
    # nothing listens on the discard port: the connection is refused until the timeout
    "scheduler": ["--omega", "4", "--shortening", "0.4", "--scheduler", "tcp://127.0.0.1:9"],
    "missing option": ["--omega", "4"],
    "closed loop without a pump": ["--scene", "heart", "--omega", "4", "--shortening", "0.4"],
    "head on a closed loop": [
        "--scene", "soft-lv", "--omega", "4", "--shortening", "0.4", "--afterload", "60",
    ],
    "uncertainty on a closed loop": [
        "--scene", "soft-lv", "--omega", "4", "--shortening", "0.4", "--uncertainty",
    ],
}  # fmt: skip
"""Each is checked through ``main`` in this process; :data:`AS_COMMANDS` also as commands."""
AS_COMMANDS = ("N < 1", "unknown scene")


@pytest.fixture(scope="module")
def cli(tmp_path_factory):
    """A small sweep and simulate at one of its points, both to the periodic steady state, at
    once (each compiles in its own process)."""
    root = tmp_path_factory.mktemp("cli")
    procs = {
        "sweep": launch("cardiosoft.sweep", *CLI_GRID, "--chunk", CHUNK, "--out", root / "sweep"),
        "simulate": launch(
            "cardiosoft.simulate",
            *("--omega", CLI_POINT["omega"], "--shortening", CLI_POINT["shortening"]),
            *("--afterload", CLI_POINT["afterload_mmHg"], "--bpm", CLI_POINT["bpm"]),
            *("--no-plot", "--out", root / "simulate"),
        ),
    }
    return {name: finish(p) for name, p in procs.items()}, root


@pytest.fixture(scope="module")
def bad_runs(tmp_path_factory):
    """The bad inputs of :data:`AS_COMMANDS` as commands, at once, each with its own output
    folder (none may appear)."""
    root = tmp_path_factory.mktemp("bad")
    procs = {
        name: launch("cardiosoft.sweep", *BAD_INPUTS[name], "--out", root / folder(name))
        for name in AS_COMMANDS
    }
    return {name: finish(p) for name, p in procs.items()}, root


def folder(name: str) -> str:
    return name.replace(" ", "-").replace("<", "lt")


@pytest.fixture(scope="module")
def swept(tmp_path_factory):
    """The grid of :data:`GRID` solved in this process into a folder."""
    out = tmp_path_factory.mktemp("swept") / "maps"
    ds = design_sweep("bench-dynamic", out=out, **KW)
    yield ds.load(), out
    ds.close()


# ------------------------------------------------------------------------------ pure helpers


def test_parse_values():
    assert parse_values("1:5:5", "omega") == (1.0, 2.0, 3.0, 4.0, 5.0)
    assert parse_values("0.4", "C") == (0.4,)
    assert parse_values("2:2:1", "C") == (2.0,)
    assert parse_values(60, "afterload") == (60.0,)
    assert parse_values([30, 90], "afterload") == (30.0, 90.0)
    for bad, words in (
        ("1:5:0", "N = 0"),
        ("1:5:2.5", "whole number"),
        ("3:3:4", "empty range"),
        ("1:5", "START:STOP:N"),
        ("a:b:c", "START:STOP:N"),
        ([], "empty range"),
        ([1, 1], "repeat"),
    ):
        with pytest.raises(ValueError, match=words) as err:
            parse_values(bad, "omega")
        assert str(err.value).startswith("omega")


@settings(max_examples=200, deadline=None)
@given(
    shape=st.lists(st.integers(1, 5), min_size=1, max_size=4),
    data=st.data(),
)
def test_boxes_cover_a_flat_range_in_order(shape, data):
    size = math.prod(shape)
    start = data.draw(st.integers(0, size - 1))
    stop = data.draw(st.integers(start + 1, size))
    index = np.arange(size).reshape(shape)
    boxes = flat_range_boxes(start, stop, shape)
    assert len(boxes) <= 2 * len(shape) - 1
    covered = np.concatenate([index[box].ravel() for box in boxes])
    np.testing.assert_array_equal(covered, np.arange(start, stop))


def test_the_package_exports_the_module_and_its_function():
    assert cardiosoft.sweep is sweep_module
    assert cardiosoft.design_sweep is design_sweep


# ------------------------------------------------------------------------------ the Dataset


def test_dataset_is_labelled(swept):
    ds, out = swept
    assert dict(ds.sizes) == {"omega": 2, "shortening": 2, "afterload_mmHg": 1, "bpm": 2}
    np.testing.assert_array_equal(ds["omega"], [3.0, 4.0])
    np.testing.assert_array_equal(ds["shortening"], [0.3, 0.4])
    np.testing.assert_array_equal(ds["bpm"], [30.0, 60.0])
    for name in (*ds.coords, *VARIABLES):
        assert ds[name].attrs.get("units"), name
    assert ds["afterload_mmHg"].attrs["units"] == "mmHg"
    assert ds["stroke_volume_ml"].attrs["units"] == "ml"
    assert ds["peak_force_N"].attrs["units"] == "N"
    assert ds["steady"].dtype == bool
    assert ds["beats"].dtype.kind == "i"
    card = cardiosoft.pump.load_card()
    assert ds.attrs["scene"] == "bench-dynamic"
    scene = json.loads(ds.attrs["scene_parameters"])
    assert scene["name"] == "bench-dynamic" and scene["effects"]
    assert ds.attrs["surrogate"] == card["name"]
    assert ds.attrs["surrogate_sha256"] == card["weights_sha256"]
    assert ds.attrs["cardiosoft_version"] == cardiosoft.__version__
    assert ds.attrs["solver_preset"] == "default"
    assert ds.attrs["precision"] == "float64"
    assert "failed_chunks" not in ds.attrs
    assert (ds["beats"] == BEATS).all()
    assert (ds["status"] != CHUNK_FAILED).all()
    assert ds["status"].attrs["flag_meanings"].split() == list(STATUS)
    # every point was solved: no padding or fill value left
    assert np.isfinite(ds["stroke_volume_ml"]).all()
    assert (ds["stroke_volume_ml"] > 10).all() and (ds["efficiency"] < 1).all()
    # the file on disk is what was returned
    xr.testing.assert_identical(ds, xr.load_dataset(out / OUTPUT))


def test_maps_and_nothing_else_written(swept):
    _, out = swept
    names = sorted(p.name for p in out.iterdir())
    maps = sorted(map_name(60.0, b) for b in (30.0, 60.0))
    assert names == sorted([OUTPUT, *maps])  # no unfinished chunks, no staging folder
    for name in maps:
        assert (out / name).read_bytes()[:8] == PNG_MAGIC


def test_rerun_refuses_to_overwrite(swept):
    _, out = swept
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    with pytest.raises(ValueError, match="exists already"):
        design_sweep("bench-dynamic", out=out, **KW)
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before


def test_in_memory_run_equals_the_file(swept):
    ds, _ = swept
    xr.testing.assert_identical(design_sweep("bench-dynamic", **KW), ds)


# ------------------------------------------------------------------------------ failures


def test_a_chunk_that_raises_fails_its_points_only(swept, monkeypatch):
    ds, _ = swept
    import cardiosoft.open_loop_tools

    solve = cardiosoft.open_loop_tools.solve_beats

    def flaky(scene, **kw):
        if np.any(np.asarray(kw["bpm"]) == 60.0) and np.any(np.asarray(kw["omega"]) == 3.0):
            raise RuntimeError("injected failure")
        return solve(scene, **kw)

    monkeypatch.setattr(cardiosoft.open_loop_tools, "solve_beats", flaky)
    got = design_sweep("bench-dynamic", **KW)
    # C order over (omega, shortening, afterload, bpm): points 1 and 3 (omega 3, bpm 60) are
    # in chunks 0 and 1, which fail whole; chunk 2 (omega 4 only) does not
    failed = np.zeros((2, 2, 1, 2), bool)
    failed.ravel()[:6] = True
    assert (got["status"].values[failed] == CHUNK_FAILED).all()
    assert not got["steady"].values[failed].any()
    assert np.isnan(got["stroke_volume_ml"].values[failed]).all()
    assert "chunk 0: RuntimeError: injected failure" in got.attrs["failed_chunks"]
    kept = ~failed
    for name in VARIABLES:
        np.testing.assert_array_equal(got[name].values[kept], ds[name].values[kept])


def test_the_summary_of_a_sweep_whose_every_point_failed_shows_no_range_and_no_warning(swept):
    """Every point failed (NaN): the printed table shows "-" for the ranges and the best design,
    and numpy's warning of an all-NaN slice does not reach the user's terminal."""
    import warnings

    from cardiosoft.sweep.cli import summary

    ds, _ = swept
    failed = ds.copy()
    for name in ("stroke_volume_ml", "peak_force_N", "efficiency"):
        failed[name] = failed[name] * np.nan
    failed["steady"] = failed["steady"] & False
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        table = summary(failed)
    rows = table.splitlines()[1:]
    assert rows and all(row.split()[-3:] == ["-", "-", "-"] for row in rows), table


def test_nan_surrogate_marks_points_not_steady_with_the_reason():
    import jax

    pump = cardiosoft.load_pump()
    pump = jax.tree_util.tree_map(lambda a: a * np.nan, pump)
    got = design_sweep("bench-dynamic", pump=pump, **KW)
    assert not got["steady"].any()
    reasons = {STATUS[s] for s in np.unique(got["status"])}
    assert reasons <= {"max_steps_reached", "nonfinite", "solver_failed"}, reasons
    assert got.attrs["surrogate"] == "in-memory PumpSurrogate"


# ------------------------------------------------------------------------------ resume


def test_interrupted_sweep_resumes_where_it_stopped(swept, tmp_path, monkeypatch):
    ds, _ = swept
    out = tmp_path / "maps"
    solve = chunk_module.solve_chunk
    solved = []

    def interrupted(task):
        if task.index == 2:
            raise KeyboardInterrupt
        solved.append(task.index)
        return solve(task)

    monkeypatch.setattr(chunk_module, "solve_chunk", interrupted)
    with pytest.raises(KeyboardInterrupt):
        design_sweep("bench-dynamic", out=out, **KW)
    assert not (out / OUTPUT).exists()
    assert sorted(p.name for p in (out / PARTIAL).glob("chunk-*")) == [
        "chunk-000000.npz",
        "chunk-000001.npz",
    ]
    with pytest.raises(ValueError, match="unfinished sweep"):
        design_sweep("bench-dynamic", out=out, **KW)
    with pytest.raises(ValueError, match="another coords"):
        design_sweep("bench-dynamic", out=out, resume=True, **(KW | {"omega": "3:5:2"}))

    solved.clear()

    def counted(task):
        solved.append(task.index)
        return solve(task)

    monkeypatch.setattr(chunk_module, "solve_chunk", counted)
    got = design_sweep("bench-dynamic", out=out, resume=True, **KW)
    assert solved == [2]
    assert not (out / PARTIAL).exists()
    xr.testing.assert_identical(got.load(), ds)
    got.close()


# ------------------------------------------------------------------------------ Dask


def test_two_dask_workers_in_this_process_give_the_same_dataset(swept, monkeypatch, tmp_path):
    """The Dask path (tasks, the window of futures, results in any order) with two worker
    threads in this process, which share its compiled solve: seconds. The same program on the
    same inputs: the Dataset is identical. Worker processes are the slow test's."""
    from distributed import Client, LocalCluster

    ds, _ = swept
    solve = chunk_module.solve_chunk
    log = tmp_path / "threads.txt"  # Dask serialises the task's function: a file is shared

    def recorded(task):
        with open(log, "a") as f:
            f.write(threading.current_thread().name + "\n")
        return solve(task)

    monkeypatch.setattr(chunk_module, "solve_chunk", recorded)
    with (
        LocalCluster(
            n_workers=2, threads_per_worker=1, processes=False, dashboard_address=None
        ) as cluster,
        Client(cluster) as client,
    ):
        got = design_sweep("bench-dynamic", client=client, **KW)
    xr.testing.assert_identical(got, ds)
    threads = log.read_text().splitlines()
    assert len(threads) == 3 and threading.main_thread().name not in threads, threads


@pytest.mark.slow
def test_two_worker_local_cluster_gives_the_same_dataset(swept):
    """Two worker processes, each compiling the solve: their numbers agree with this
    process's to round-off (another process, possibly another CPU: not bit for bit)."""
    ds, _ = swept
    got = design_sweep("bench-dynamic", workers=2, **KW)
    xr.testing.assert_allclose(got, ds, rtol=1e-12, atol=0)
    for name in ("beats", "steady", "status", "flagged"):
        xr.testing.assert_equal(got[name], ds[name])


# ------------------------------------------------------------------------------ command line


@pytest.mark.slow
def test_command_line_writes_the_dataset_and_maps(cli):
    done, root = cli
    run = done["sweep"]
    assert run.returncode == 0, run.stderr
    out = root / "sweep"
    assert sorted(p.name for p in out.iterdir()) == sorted([OUTPUT, map_name(60.0, 60.0)])
    assert "best efficiency" in run.stdout
    with xr.open_dataset(out / OUTPUT) as ds:
        assert dict(ds.sizes) == {"omega": 2, "shortening": 1, "afterload_mmHg": 1, "bpm": 1}


@pytest.mark.slow
def test_grid_point_equals_simulate_at_that_design(cli):
    """The sweep's point and ``python -m cardiosoft.simulate`` at its design agree to 1e-6, at
    the periodic steady state (the sweep's point solved in a batch of two, simulate's alone)."""
    done, root = cli
    assert done["simulate"].returncode == 0, done["simulate"].stderr
    (record,) = json.loads((root / "simulate" / "summary.json").read_text())["records"]
    with xr.open_dataset(root / "sweep" / OUTPUT) as ds:
        point = ds.sel(CLI_POINT).load()
    for mine, theirs in PAIRS.items():
        assert float(point[mine]) == pytest.approx(record[theirs], rel=1e-6), mine
    assert int(point["beats"]) == record["beats"]
    assert bool(point["steady"]) and record["ok"]
    # a difference of two states of ~100 (ml, ml/s, mmHg): held to what the states agree to
    # (1e-6 of ~100), not relative to its own size (measured: 1.8e-8 apart on 5.9e-3)
    assert float(point["residual"]) == pytest.approx(record["steady_residual"], abs=1e-4)


def test_grid_points_equal_simulate_at_their_designs(tmp_path, swept):
    """Three points of a sweep (one chunk: the module's compiled solve) against ``simulate``
    (its ``main()`` in this process: ``run()``'s own solve, which saves the traces) at the same
    design, heads, rate and beats: the same equations along two paths, so the metrics agree to
    1e-9 relative (the steps are the solver's own in both: round-off). ``flagged`` is what
    simulate's flags say."""
    from cardiosoft import simulate

    heads = [30.0, 60.0, 90.0]
    got = design_sweep(
        "bench-dynamic",
        omega=4.0,
        shortening=0.4,
        afterload=heads,
        bpm=60,
        beats=BEATS,
        chunk=CHUNK,
        progress=False,
    )
    argv = ["--omega", "4", "--shortening", "0.4", "--bpm", "60", "--beats", str(BEATS)]
    argv += ["--afterload", *map(str, heads), "--no-plot", "--quiet", "--out", str(tmp_path)]
    assert simulate.main(argv) == 0
    records = json.loads((tmp_path / "summary.json").read_text())["records"]
    for head, record in zip(heads, records, strict=True):
        point = got.sel(omega=4.0, shortening=0.4, afterload_mmHg=head, bpm=60.0)
        for mine, theirs in PAIRS.items():
            if record[theirs] is None:  # reported as none by run(): flagged as not meaningful
                assert record["flags"], theirs
                continue
            assert float(point[mine]) == pytest.approx(record[theirs], rel=1e-9), (head, mine)
        assert int(point["beats"]) == record["beats"] == BEATS
        assert bool(point["flagged"]) == bool(record["flags"])
        # a difference of two states of ~100 (ml, ml/s, mmHg): held to what the states
        # themselves agree to, not relative to its own size
        assert float(point["residual"]) == pytest.approx(record["steady_residual"], abs=1e-6)


@pytest.mark.slow
def test_closed_loop_grid_points_equal_simulate_at_their_designs(tmp_path):
    """A closed loop swept (``soft-lv``: the design is its pump's): each point's variables are
    ``summary.json``'s numbers of the same name from ``simulate`` at that design (its own
    solve, one member), and those of ``run_designs`` at the same designs; its maps' panels are
    the pump's stroke volume, the cardiac output and the pump's force.

    The two solves are the same equations, but not the same steps: a batch of two rounds
    otherwise than a batch of one, and near the valves' switches that flips the step
    controller's choices. So they agree to the integration's accuracy, not to round-off: at the
    default preset 1e-4 apart (measured), at "reference" (rtol 1e-10) at most 6.6e-10; held to
    1e-8, 100 times that rtol."""
    from cardiosoft import simulate

    omegas = [3.5, 4.5]
    got = design_sweep(
        "soft-lv", omega=omegas, shortening=0.45, bpm=60, beats=2, accuracy="reference",
        chunk=2, progress=False,
    )  # fmt: skip
    assert dict(got.sizes) == {"omega": 2, "shortening": 1, "bpm": 1}
    assert got["left_sv_ml"].attrs["units"] == "ml"
    assert "right_peak_force_N" not in got  # the right ventricle is native
    panels = [p[0] for p in json.loads(got.attrs["map_panels"])]
    assert panels == ["left_sv_ml", "left_co_l_min", "left_peak_force_N"]
    numbers = [v for v in got.data_vars if got[v].attrs["units"] != "1" or v.endswith("_ef")]
    assert len(numbers) >= 15
    for omega in omegas:
        out = tmp_path / f"omega-{omega:g}"
        argv = ["--scene", "soft-lv", "--omega", str(omega), "--shortening", "0.45"]
        argv += ["--bpm", "60", "--beats", "2", "--accuracy", "reference"]
        argv += ["--no-plot", "--quiet", "--out", str(out)]
        assert simulate.main(argv) == 0
        (record,) = json.loads((out / "summary.json").read_text())["records"]
        point = got.sel(omega=omega, shortening=0.45, bpm=60.0)
        for name in numbers:
            assert float(point[name]) == pytest.approx(record[name], rel=1e-8), (omega, name)
        assert int(point["beats"]) == record["beats"] == 2
        assert bool(point["flagged"]) == bool(record["flags"])
    # run_designs: the same designs as one batch of labelled records
    designs = cardiosoft.run_designs(
        "soft-lv", designs=[(o, 0.45) for o in omegas], bpm=60, beats=2, accuracy="reference"
    )
    records = cardiosoft.summary_records(designs)
    assert [r["label"] for r in records] == [f"Omega {o:g}, C 0.45" for o in omegas]
    for omega, record in zip(omegas, records, strict=True):
        point = got.sel(omega=omega, shortening=0.45, bpm=60.0)
        for name in numbers:
            assert float(point[name]) == pytest.approx(record[name], rel=1e-8), (omega, name)


def one_error_line(stderr: str) -> bool:
    lines = stderr.strip().splitlines()
    return len(lines) == 1 and lines[0].startswith("error: ")


@pytest.mark.parametrize("name", list(BAD_INPUTS))
def test_bad_input_exits_2_with_one_line_and_writes_nothing(name, tmp_path, capfd):
    out = tmp_path / folder(name)
    with pytest.raises(SystemExit) as exited:
        raise SystemExit(sweep_module.main([*BAD_INPUTS[name], "--out", str(out)]))
    assert exited.value.code == 2
    captured = capfd.readouterr()
    assert one_error_line(captured.err), captured.err
    assert captured.out == ""
    assert not out.exists()


@pytest.mark.parametrize("name", AS_COMMANDS)
def test_bad_input_as_a_command(bad_runs, name):
    done, root = bad_runs
    run = done[name]
    assert run.returncode == 2, (run.stdout, run.stderr)
    assert one_error_line(run.stderr), run.stderr
    assert run.stdout == ""
    assert not (root / folder(name)).exists()


def test_help_runs_without_the_runpy_warning(tmp_path):
    out = subprocess.run(
        [sys.executable, "-W", "error::RuntimeWarning", "-m", "cardiosoft.sweep", "--help"],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=tmp_path,
    )
    assert out.returncode == 0, out.stderr
    assert "usage: python -m cardiosoft.sweep" in out.stdout


# slow (46 s): CI keeps its 20-minute budget; tests/test_posterior.py checks simulate's own
# bands in CI, and this test that the sweep's equal them.
@pytest.mark.slow
def test_uncertainty_adds_the_bands_that_simulate_computes():
    """``uncertainty=N``: each point's band variables are the predictive bands that
    cardiosoft.posterior gives the same member by itself (the path of simulate
    --uncertainty); the tolerance is the solver's (the batches differ in size)."""
    from cardiosoft.posterior import ensemble_run, first_draws, predictive_bands
    from cardiosoft.pump import load_posterior
    from cardiosoft.units import mmHg

    ds = design_sweep(
        "bench-dynamic", omega=4.0, shortening=0.4, afterload=60, bpm=30, beats=2,
        uncertainty=4, progress=False,
    )
    post = first_draws(load_posterior(), 4)
    scene = cardiosoft.load_scene("bench-dynamic").replace(bpm=30)
    ens = ensemble_run(scene, post, afterload=60 * mmHg, beats=2)
    band = predictive_bands(ens, post.card)[0]["dynamic_sv_ml"]
    low, high = (float(ds[f"stroke_volume_ml_band_{e}"].values.ravel()[0])
                 for e in ("low", "high"))
    assert low == pytest.approx(band.low, rel=1e-5)
    assert high == pytest.approx(band.high, rel=1e-5)
    assert ds.attrs["uncertainty_draws"] == 4


def test_uncertainty_refuses_draws_beyond_the_posterior():
    with pytest.raises(ValueError, match="draws = 1000"):
        design_sweep("bench-dynamic", omega=4.0, shortening=0.4, uncertainty=1000,
                     progress=False)
