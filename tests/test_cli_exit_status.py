"""Exit status of the commands (DESIGN.md section 4, issue 23 item 7): a flag is a warning (exit
0; ``--strict``: 1), a member that failed or missed the steady state it was asked to reach is a
failure (exit 1), bad input is 2 (one line).

The rule itself is checked on constructed members, datasets and suite outcomes (no solve):
whichever member the model gives today, each kind is present. The commands are then run where
it is cheap (the quasi-static bench, no ODE) and held to what the API says of the same members.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import xarray as xr

import cardiosoft as cs
from cardiosoft import simulate
from cardiosoft.console import Console, report_members
from cardiosoft.results import MemberResult
from cardiosoft.stress.checks import Outcome
from cardiosoft.stress.cli import report_outcomes
from cardiosoft.stress.report import SuiteReport
from cardiosoft.sweep import NOT_STEADY, OK, SOLVER_FAILED, STATUS
from cardiosoft.sweep.cli import report_points

TRANSIENT = "not steady after 3 beats (cycle change 0.2 > 0.01): a transient"
SOLVER = "solver failed in beat 2: The maximum number of solver steps was reached."
RANGE_FLAG = "pump pressure up to 167.1 mmHg, above the fitted 150 mmHg"


def member(ok=True, message="ok", flags=()):
    return MemberResult("60 mmHg", None, ok, message, 3, 0.0, 0.0, {}, {}, tuple(flags))


@pytest.mark.parametrize(
    "members, steady_asked, status, strict_status, prefixes",
    [
        ([member()], True, 0, 0, []),
        ([member(flags=[RANGE_FLAG])], True, 0, 1, ["warning"]),
        ([member(False, TRANSIENT)], True, 1, 1, ["failed"]),  # asked for the steady state
        ([member(False, TRANSIENT)], False, 0, 1, ["warning"]),  # --beats N: a transient flag
        ([member(False, SOLVER)], False, 1, 1, ["failed"]),
        ([member(False, "something new")], False, 1, 1, ["failed"]),  # unknown: not excused
        ([member(), member(False, SOLVER, [RANGE_FLAG])], True, 1, 1, ["failed", "warning"]),
    ],
)
def test_flags_warn_failures_fail(members, steady_asked, status, strict_status, prefixes, capsys):
    for strict in (False, True):
        console = Console(strict=strict)
        report_members(console, members, steady_asked=steady_asked)
        assert console.status() == (strict_status if strict else status)
        lines = capsys.readouterr().err.splitlines()
        assert [line.split(":")[0] for line in lines] == prefixes
        assert console.record()["exit_status"] == console.status()
    quiet = Console(quiet=True)
    report_members(quiet, members, steady_asked=steady_asked)
    # --quiet: no warnings, but a failure is still said
    assert [line.split(":")[0] for line in capsys.readouterr().err.splitlines()] == [
        p for p in prefixes if p == "failed"
    ]
    assert quiet.status() == status and len(quiet.flags) == prefixes.count("warning")


def dataset(status, flagged, beats=40):
    status = np.asarray(status, np.int8)
    dims = ("omega",)
    return xr.Dataset(
        {"status": (dims, status), "flagged": (dims, np.asarray(flagged, bool))},
        attrs={"max_beats": beats},
    )


@pytest.mark.parametrize(
    "status, flagged, fixed_beats, expected, strict_expected",
    [
        ([OK, OK], [False, False], False, 0, 0),
        ([OK, OK], [True, False], False, 0, 1),  # flagged numbers: a warning
        ([OK, NOT_STEADY], [False, False], False, 1, 1),  # to the steady state: a failure
        ([OK, NOT_STEADY], [False, False], True, 0, 1),  # --beats N: a transient is a flag
        ([OK, SOLVER_FAILED], [False, False], True, 1, 1),
        ([STATUS.index("chunk_failed")], [False], True, 1, 1),
    ],
)
def test_sweep_points_decide_the_exit_status(
    status, flagged, fixed_beats, expected, strict_expected, capsys
):
    for strict, want in ((False, expected), (True, strict_expected)):
        console = Console(strict=strict)
        report_points(console, dataset(status, flagged), fixed_beats)
        assert console.status() == want
    err = capsys.readouterr().err
    assert ("failed:" in err) == (expected == 1)


def test_stress_failed_cases_fail_known_ones_are_flags_flagged_ones_neither(capsys):
    case = cs.stress.Case("grid/x", "grid", "bench-static", (), 4.0, 0.4, None, 30.0)
    outcomes = {
        "passed": Outcome(case, "passed"),
        "flagged": Outcome(case, "flagged", (), ("pump pressure up to 151 mmHg",)),
        "known": Outcome(case, "known", (("finite", "x"),), (), ("a known bug",)),
        "failed": Outcome(case, "failed", (("volume", "drifts by 1e-6"),)),
    }
    expected = {"passed": (0, 0), "flagged": (0, 0), "known": (0, 1), "failed": (1, 1)}
    for name, outcome in outcomes.items():
        for strict, want in zip((False, True), expected[name], strict=True):
            console = Console(strict=strict)
            report_outcomes(console, SuiteReport([outcome]))
            assert console.status() == want, (name, strict)
    err = capsys.readouterr().err
    assert "failed: grid/x: volume: drifts by 1e-6" in err


def test_simulate_exit_status_and_flags_follow_the_api(tmp_path, capsys):
    """The quasi-static bench at the largest head (no ODE: seconds): exit 0 whatever is flagged,
    1 with --strict exactly when the API flags a member; summary.json lists the API's flags."""
    api = cs.summary_records(cs.run("bench-static", afterload=[0.0, 150.0]))
    flags = [f"{r['label']}: {f}" for r in api for f in r["flags"]]
    argv = ["--scene", "bench-static", "--afterload", "0", "150", "--no-plot"]
    assert simulate.main([*argv, "--out", str(tmp_path / "a")]) == 0
    err = capsys.readouterr().err
    assert [line for line in err.splitlines() if line.startswith("warning:")] == [
        f"warning: {f}" for f in flags
    ]
    written = json.loads((tmp_path / "a" / "summary.json").read_text())
    assert written["flags"] == flags and written["failures"] == []
    assert written["exit_status"] == 0
    strict = simulate.main([*argv, "--out", str(tmp_path / "b"), "--strict", "--quiet"])
    assert strict == (1 if flags else 0)
    assert capsys.readouterr().err == ""  # --quiet: warnings are not printed, only recorded
    assert json.loads((tmp_path / "b" / "summary.json").read_text())["flags"] == flags


def test_simulate_verify_on_a_small_run(tmp_path, capsys):
    """``--verify`` on the quasi-static bench: summary.json's verification is the API's
    (``verify_run`` of the same run), and the stroke volume, set by a root find that converges to
    round-off, differs from its 10x finer rerun by round-off only (the pull grid sets the force,
    not the volume: cardiosoft.verify)."""
    argv = ["--scene", "bench-static", "--afterload", "30", "90", "--verify", "--no-plot"]
    assert simulate.main([*argv, "--out", str(tmp_path), "--quiet"]) == 0
    written = json.loads((tmp_path / "summary.json").read_text())["verification"]
    api = cs.verify_run(cs.run("bench-static", afterload=[30.0, 90.0])).record()
    assert written["reference_setting"] == api["reference_setting"]
    assert written["ok"] is True and api["ok"] is True
    assert [m["label"] for m in written["members"]] == [m["label"] for m in api["members"]]
    for mine, theirs in zip(written["members"], api["members"], strict=True):
        assert set(mine["metrics"]) == set(theirs["metrics"])
        for key, v in theirs["metrics"].items():
            for part in ("run", "reference"):
                if v[part] is None:
                    assert mine["metrics"][key][part] is None, (key, part)
                else:  # the same functions along two paths: round-off
                    assert mine["metrics"][key][part] == pytest.approx(v[part], rel=1e-12)
        difference = mine["metrics"]["static_sv_ml"]["difference"]
        assert abs(difference) < 1e-6, difference  # ml
