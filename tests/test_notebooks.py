"""Execute every notebook in notebooks/ and check one key number of each against its source.

Jupyter is not a dependency: a notebook is read as nbformat-4 JSON, its code cells are joined and
``exec``-ed in a fresh namespace with the working directory at the repository root and the Agg
backend, the way ``jupyter nbconvert --execute`` would run them top to bottom. Notebooks are
stored without outputs.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import pytest

ROOT = Path(__file__).resolve().parent.parent
NOTEBOOKS = sorted((ROOT / "notebooks").glob("*.ipynb"))


def read_notebook(path: Path) -> dict:
    nb = json.loads(path.read_text(encoding="utf-8"))
    assert nb.get("nbformat") == 4, f"{path.name}: not an nbformat-4 notebook"
    assert isinstance(nb.get("cells"), list), f"{path.name}: no cell list"
    for i, cell in enumerate(nb["cells"]):
        assert cell.get("cell_type") in ("code", "markdown", "raw"), f"{path.name} cell {i}"
        assert isinstance(cell.get("source"), (list, str)), f"{path.name} cell {i}: no source"
    return nb


def code_cells(nb: dict) -> list[str]:
    return [
        "".join(cell["source"]) if isinstance(cell["source"], list) else cell["source"]
        for cell in nb["cells"]
        if cell["cell_type"] == "code"
    ]


def execute(path: Path, monkeypatch) -> dict:
    """Run the notebook's code cells in order; return the namespace they left."""
    nb = read_notebook(path)
    stored = [
        i
        for i, cell in enumerate(nb["cells"])
        if cell["cell_type"] == "code"
        and (cell.get("outputs") or cell.get("execution_count") is not None)
    ]
    assert not stored, f"{path.name}: cells {stored} have stored outputs; clear them"
    cells = code_cells(nb)
    assert cells, f"{path.name}: no code cells"
    source = "\n\n".join(cells)
    monkeypatch.chdir(ROOT)
    plt.switch_backend("Agg")
    namespace = {"__name__": "__main__", "__file__": str(path)}
    try:
        exec(compile(source, str(path), "exec"), namespace)
    finally:
        plt.close("all")
    return namespace


def read_csv(path: Path) -> list[dict]:
    with open(path, newline="", encoding="utf-8") as f:
        lines = [line for line in f if line.strip() and not line.startswith("#")]
    return list(csv.DictReader(lines))


def check_fig7(ns: dict) -> None:
    # the paper's analysis-A3 boundary conditions (section II-D) and cavity (section II-F)
    assert ns["anchor_dz_mm"] == pytest.approx(19.8, abs=0.1)
    assert ns["anchor_dalpha_deg"] == pytest.approx(99.8, abs=0.1)
    assert ns["cavity_ml"] == pytest.approx(108.6, abs=0.05)


def check_tables(ns: dict) -> None:
    # the model card records the metrics computed when the artifact was fitted
    card = json.loads((ROOT / "surrogates" / "ss950-v2.json").read_text())["metrics"]
    assert ns["mae_table2_ml"] == pytest.approx(card["table2_mae_ml"], rel=1e-9)
    assert ns["mae_table1_ml"] == pytest.approx(card["table1_mae_ml"], rel=1e-9)
    assert ns["folds_wrong"] == card["folds_wrong"]
    assert ns["folds_right"] + ns["folds_wrong"] == 25 + 9


def check_fig10(ns: dict) -> None:
    paper = read_csv(ROOT / "fit" / "data" / "fig10_bench.csv")
    model = np.asarray(ns["static_sv_ml"])
    assert model.shape == (len(paper),)
    for row, sv in zip(paper, model, strict=True):
        mean, sd = float(row["static_sv_ml"]), float(row["static_sv_sd_ml"])
        assert abs(sv - mean) <= sd, (row["afterload_mmHg"], sv, mean, sd)


CHECKS = {
    "fig7_apex_motion": check_fig7,
    "tables_fit": check_tables,
    "fig10_bench": check_fig10,
}
SLOW = {"fig10_bench"}  # a diffrax run of three afterloads to steady state, ~20 s


def _param(path: Path):
    marks = [pytest.mark.slow] if path.stem in SLOW else []
    return pytest.param(path, id=path.stem, marks=marks)


def test_every_notebook_has_a_check():
    assert NOTEBOOKS, "no notebooks found"
    assert {p.stem for p in NOTEBOOKS} == set(CHECKS)


@pytest.mark.parametrize("path", [_param(p) for p in NOTEBOOKS])
def test_notebook_runs(path: Path, monkeypatch):
    ns = execute(path, monkeypatch)
    CHECKS[path.stem](ns)
