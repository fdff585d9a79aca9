"""The SV bands of a design and the robust design search (cardiosoft.design.robust, issue #24).

Independent sources: the discrepancy law written out by hand; the design's own verifying run.
"""

import json
import math
from types import SimpleNamespace

import pytest

from cardiosoft.design import cli
from cardiosoft.design.robust import robust_design
from cardiosoft.scene import load_scene

CARD = {"discrepancy": {
    "distance": {"rate_bpm": 30.0, "rate_scale_bpm": 30.0, "afterload_mmHg": [30.0, 90.0],
                 "afterload_scale_mmHg": 30.0},
    **{k: {"s0": 1e-6, "s1": 2e-6} for k in ("static_sv", "dynamic_sv", "force", "work")},
}}  # s0 1 ml, s1 2 ml


def _result(tol):
    target = SimpleNamespace(bpm=60.0, afterload_mmHg=60.0, target_sv_ml=70.0,
                             where="60 mmHg, 60 bpm")
    return SimpleNamespace(tolerance_ml=tol, targets=(target,),
                           design={"omega": 4.0, "shortening": 0.4})


def test_no_design_is_robust_below_the_discrepancys_own_band():
    """At 60 bpm (one rate scale from 30) the SV discrepancy's sd is sqrt(1 + 4 (1 - e^-1)) ml:
    a tolerance below 1.96 times it cannot be met by any design, and no solve is spent."""
    floor = 1.959963984540054 * math.sqrt(1 + 4 * (1 - math.exp(-1)))
    found = robust_design(load_scene("bench-dynamic"), _result(floor - 0.01),
                          SimpleNamespace(card=CARD), progress=lambda m: None)
    assert not found.within and found.omega is None
    assert f"+- {floor:.2f} ml" in found.reason


def test_design_uncertainty_is_refused_on_a_closed_loop(capsys):
    assert cli.main(["--scene", "tah", "--target-co", "5", "--uncertainty"]) == 2
    assert "--uncertainty" in capsys.readouterr().err


@pytest.mark.slow
def test_design_reports_the_band_of_the_sv_it_reaches(tmp_path):
    """``design --uncertainty``: design.json holds the SV's band, which contains the SV the
    verifying run reached (the shipped surrogate is the posterior's centre)."""
    out = tmp_path / "d"
    status = cli.main(["--target-sv", "70", "--afterload", "60", "--bpm", "30",
                       "--uncertainty", "--draws", "16", "--no-plot", "--out", str(out),
                       "--quiet"])
    assert status == 0
    record = json.loads((out / "design.json").read_text())
    (low, high), = record["uncertainty"]["sv_band_ml"]
    assert low < record["targets"][0]["sv_ml"] < high
