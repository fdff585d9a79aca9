"""``python -m cardiosoft.simulate`` as a subprocess: outputs, the no-overwrite rule, bad input,
and the paper comparison.

Every invocation costs an interpreter start and, for a real run, a compile (~10 s), so the runs
are shared through module fixtures and launched concurrently. The files written are checked
against each other (summary.json against traces.csv, by scipy quadrature) and against the paper's
values read from the dataset.
"""

import csv
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import simpson

from cardiosoft.datasets import load_paper_data

REPO = Path(__file__).resolve().parent.parent
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
RECORD_KEYS = {
    "afterload_mmHg",
    "static_sv_ml",
    "dynamic_sv_ml",
    "peak_force_N",
    "mech_work_J",
    "efficiency",
    "ef",
    "beats",
}
MMHG = 133.322387415  # Pa


def launch(*args):
    return subprocess.Popen(
        [sys.executable, "-m", "cardiosoft.simulate", *map(str, args)],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def finish(proc, timeout=300):
    out, err = proc.communicate(timeout=timeout)
    return subprocess.CompletedProcess(proc.args, proc.returncode, out, err)


def snapshot(folder):
    return {p.name: (p.stat().st_mtime_ns, p.read_bytes()) for p in sorted(folder.iterdir())}


BAD_INPUTS = {
    "bpm": ["--bpm", "-5"],
    "shortening": ["--shortening", "1.2"],
    "scene": ["--scene", "nope"],
    "afterload": ["--afterload", "nan"],
    "omega": ["--omega", "7"],
    "pump": ["--pump", "ss950-v9"],
    "effect": ["--add-effect", "column_wobble"],
}


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Every invocation at once (one real compile among them), then a rerun that must refuse to
    overwrite the first run's files."""
    root = tmp_path_factory.mktemp("simulate")
    full, static = root / "bpm30", root / "static"
    procs = {
        "full": launch("--bpm", 30, "--compare-paper", "--out", full),
        "static": launch("--scene", "bench-static", "--no-plot", "--out", static),
        "static_v4": launch(
            "--scene", "bench-static", "--pump", "ss950-v4", "--no-plot", "--out", root / "v4"
        ),
    }
    procs |= {name: launch(*args, "--out", root / name) for name, args in BAD_INPUTS.items()}
    done = {name: finish(p) for name, p in procs.items()}
    before = snapshot(full) if full.is_dir() else {}
    done["again"] = finish(launch("--bpm", 30, "--out", full))
    return done, root, before


def test_run_writes_summary_traces_and_figure(runs):
    done, root, _ = runs
    full = root / "bpm30"
    result = done["full"]
    assert result.returncode == 0, result.stderr
    assert sorted(p.name for p in full.iterdir()) == ["figure.png", "summary.json", "traces.csv"]
    assert (full / "figure.png").read_bytes()[:8] == PNG_MAGIC
    summary = json.loads((full / "summary.json").read_text())
    assert summary["scene"] == "bench-dynamic" and summary["bpm"] == 30
    records = summary["records"]
    assert [r["afterload_mmHg"] for r in records] == [30, 60, 90]
    for r in records:
        assert RECORD_KEYS <= set(r)
        assert r["ok"] is True
        assert 1 <= r["beats"] <= 40
        for key in RECORD_KEYS - {"beats"}:
            assert math.isfinite(r[key]) and r[key] > 0, (key, r[key])
    printed = result.stdout
    for r in records:
        assert f"{r['dynamic_sv_ml']:.1f}" in printed


def test_pump_option_runs_the_named_surrogate_with_its_rig(runs):
    """``--pump ss950-v4`` on the static bench: the scene takes that pump's calibration (its
    model card's column and friction), so its static SVs are the ones its fit recorded (the
    same quasi-static pull; 1e-3 covers the pull grid, 201 points there)."""
    from cardiosoft.pump import load_card

    done, root, _ = runs
    assert done["static_v4"].returncode == 0, done["static_v4"].stderr
    assert "pump ss950-v4" in done["static_v4"].stdout
    v4 = json.loads((root / "v4" / "summary.json").read_text())
    v3 = json.loads((root / "static" / "summary.json").read_text())
    assert v4["pump"] == "ss950-v4" and v3["pump"] == "ss950-v3"
    card = load_card("ss950-v4")["metrics"]
    sv = [r["static_sv_ml"] for r in v4["records"]]
    np.testing.assert_allclose(sv, card["static_sv_ml"], rtol=1e-3)
    force = [r["peak_force_N"] for r in v4["records"]]
    np.testing.assert_allclose(force, card["peak_force_N"], rtol=1e-3)
    assert [r["peak_force_N"] for r in v3["records"]] != pytest.approx(force, rel=1e-2)


def read_traces(folder):
    with open(folder / "traces.csv", newline="") as f:
        rows = list(csv.reader(f))
    return rows[0], rows[1:]


def test_traces_agree_with_the_summary(runs):
    _, root, _ = runs
    full = root / "bpm30"
    header, rows = read_traces(full)
    assert header[:4] == ["member", "time_s", "pull_mm", "volume_ml"]
    assert {"cable_force_N", "column_volume_ml", "outflow_ml_per_s"} <= set(header)
    col = {name: i for i, name in enumerate(header)}
    records = json.loads((full / "summary.json").read_text())["records"]
    assert sorted({row[0] for row in rows}) == sorted(r["label"] for r in records)
    for r in records:
        mine = [row for row in rows if row[0] == r["label"]]
        assert len(mine) > 100

        def column(name, mine=mine):
            return np.array([float(row[col[name]]) for row in mine])

        volume = column("volume_ml")
        sv = volume.max() - volume.min()
        assert r["dynamic_sv_ml"] == pytest.approx(sv, rel=1e-6)
        assert r["ef"] == pytest.approx(sv / volume.max(), rel=1e-6)
        pull_m = column("pull_mm") * 1e-3
        force = column("cable_force_N")
        pulling = np.arange(int(np.argmax(pull_m)) + 1)  # from rest to full pull
        work = simpson(force[pulling], x=pull_m[pulling])
        assert r["mech_work_J"] == pytest.approx(work, rel=1e-3)
        assert r["efficiency"] == pytest.approx(
            r["afterload_mmHg"] * MMHG * sv * 1e-6 / work, rel=1e-3
        )


def test_rerun_without_force_refuses_and_leaves_files_untouched(runs):
    done, root, before = runs
    full = root / "bpm30"
    result = done["again"]
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert "--force" in lines[0] and "exists" in lines[0]
    assert result.stdout == ""
    assert before and snapshot(full) == before


def test_no_plot_writes_no_figure(runs):
    """The static bench (no ODE, so no compile) with --no-plot: summary and traces only."""
    done, root, _ = runs
    result = done["static"]
    assert result.returncode == 0, result.stderr
    folder = root / "static"
    assert sorted(p.name for p in folder.iterdir()) == ["summary.json", "traces.csv"]
    records = json.loads((folder / "summary.json").read_text())["records"]
    paper = load_paper_data().fig10_bench
    for r, sv, sd in zip(records, paper["static_sv_ml"], paper["static_sv_sd_ml"], strict=True):
        assert r["beats"] == 0 and r["dynamic_sv_ml"] is None
        assert abs(r["static_sv_ml"] - sv) <= sd


def test_compare_paper_prints_the_papers_30_bpm_values(runs):
    done, _, _ = runs
    result = done["full"]
    assert result.returncode == 0, result.stderr
    paper = load_paper_data().fig10_bench
    assert "71.3" in result.stdout and "54.4" in result.stdout
    assert "paper: 30 bpm" in result.stdout
    paper_rows = [line.split() for line in result.stdout.splitlines() if "paper" in line.split()]
    assert len(paper_rows) == len(paper)
    for i, row in enumerate(paper_rows):
        assert row[1:4] == [
            f"{paper['static_sv_ml'][i]:.1f}",
            f"{paper['dynamic_sv_ml'][i]:.1f}",
            f"{paper['peak_force_N'][i]:.1f}",
        ]
        assert f"{paper['efficiency'][i]:.3f}" in row


@pytest.mark.parametrize("name", list(BAD_INPUTS))
def test_bad_input_exits_2_with_one_line_naming_it_and_writes_nothing(runs, name):
    done, root, _ = runs
    result = done[name]
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert name in lines[0]
    assert BAD_INPUTS[name][1] in lines[0]
    assert "Traceback" not in result.stderr
    assert result.stdout == ""
    assert not (root / name).exists()
