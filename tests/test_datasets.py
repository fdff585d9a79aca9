"""The shipped paper data load, match the paper's text, and malformed files are refused."""

import math
import re
from pathlib import Path

import numpy as np
import pytest

from cardiosoft import datasets
from cardiosoft.datasets import load, load_paper_data
from cardiosoft.files import sha256

ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT / "fit" / "data"
# The paper's text is not shipped (copyright); it is laid beside the repository, as
# `<repository>/../shared/paper/`, in the project's workspaces and in CI's clone.
PAPER = ROOT.parent / "shared" / "paper" / "soft-pump-paper.txt"


@pytest.fixture(scope="module")
def paper():
    return load_paper_data()


def _row(ds, **where):
    mask = np.ones(len(ds), dtype=bool)
    for name, value in where.items():
        mask &= np.isclose(ds[name], value)
    (idx,) = np.nonzero(mask)
    assert len(idx) == 1, (where, idx)
    return ds.row(int(idx[0]))


# ---------------------------------------------------------------- shipped files


def test_shipped_files_load_with_counts(paper):
    assert [d.kind for d in paper] == list(datasets.KINDS)
    assert len(paper.table1_fem) == 25
    assert len(paper.table2_experiment) == 9
    assert len(paper.fig10_bench) == 3
    assert len(paper.fem_comparisons) == 6
    for d in paper:
        assert all(p.strip() for p in d.provenance)
        assert d.sha256 == sha256(d.path)
        assert re.fullmatch(r"[0-9a-f]{64}", d.sha256)
    assert set(paper.hashes()) == {f"{k}.csv" for k in datasets.KINDS}


def test_default_root_is_repo_fit_data(paper):
    assert datasets.default_root() == DATA
    assert paper.table1_fem.path == DATA / "table1_fem.csv"
    assert load_paper_data(DATA).hashes() == paper.hashes()


def test_table1_grid_and_spot_values(paper):
    t1 = paper.table1_fem
    pairs = {(o, c) for o, c in zip(t1["omega"], t1["shortening"], strict=True)}
    assert pairs == {(o, c) for o in (1.0, 2.0, 3.0, 4.0, 5.0) for c in (0.2, 0.3, 0.4, 0.5, 0.6)}
    assert t1["folds"].dtype == np.int64
    r = _row(t1, omega=4, shortening=0.4)
    assert (r["ef_percent"], r["folds"]) == (75.2, 4)
    r = _row(t1, omega=1, shortening=0.6)
    assert (r["ef_percent"], r["folds"]) == (68.3, 3)
    assert _row(t1, omega=1, shortening=0.2)["ef_percent"] == 32.8
    assert _row(t1, omega=5, shortening=0.6)["ef_percent"] == 89.2
    # Three folds exactly at Omega = 1, C >= 0.4 (Sec. III-C); four everywhere else.
    three = {
        (o, c) for o, c, f in zip(t1["omega"], t1["shortening"], t1["folds"], strict=True) if f == 3
    }
    assert three == {(1.0, 0.4), (1.0, 0.5), (1.0, 0.6)}
    assert set(t1.provenance) == {"Table I"}


def test_table2_spot_values_and_mean_error(paper):
    t2 = paper.table2_experiment
    r = _row(t2, omega=1, shortening=0.4)
    assert (r["ef_percent"], r["folds"], r["error_ml"]) == (58.3, 3, 3.7)
    assert _row(t2, omega=1, shortening=0.6)["error_ml"] == 3.0
    assert _row(t2, omega=2, shortening=0.5)["error_ml"] == 0.4
    # Folds are 3 exactly at Omega = 1, and 4 elsewhere.
    assert np.all((t2["folds"] == 3) == (t2["omega"] == 1))
    # "The mean error in the inner volume prediction ... is 2 ml only"; highest 3.7 and 3 ml.
    assert round(float(np.mean(t2["error_ml"])), 1) == 2.0
    assert sorted(t2["error_ml"])[-2:] == [3.0, 3.7]
    assert set(t2.provenance) == {"Table II"}
    # Every Table II case is one of Table I's grid points.
    t1 = paper.table1_fem
    grid = set(zip(t1["omega"], t1["shortening"], strict=True))
    assert set(zip(t2["omega"], t2["shortening"], strict=True)) <= grid


def test_fig10_values(paper):
    b = paper.fig10_bench
    np.testing.assert_array_equal(b["afterload_mmHg"], [30, 60, 90])
    np.testing.assert_array_equal(b["static_sv_ml"], [67.8, 60.2, 55.7])
    np.testing.assert_array_equal(b["static_sv_sd_ml"], [2.6, 1.2, 1.2])
    np.testing.assert_array_equal(b["dynamic_sv_ml"], [71.3, 68.7, 66.9])
    np.testing.assert_array_equal(b["dynamic_sv_sd_ml"], [1.4, 1.1, 1.7])
    np.testing.assert_array_equal(b["peak_force_N"], [54.4, 84.2, 93.3])
    np.testing.assert_array_equal(b["peak_force_sd_N"], [1.6, 1.1, 0.2])
    np.testing.assert_array_equal(b["efficiency"], [0.168, 0.246, 0.301])
    assert np.all(b["omega"] == 4) and np.all(b["shortening"] == 0.4) and np.all(b["bpm"] == 30)
    r = _row(b, afterload_mmHg=30)
    assert (r["static_sv_ml"], r["static_sv_sd_ml"]) == (67.8, 2.6)
    r = _row(b, afterload_mmHg=90)
    assert (r["peak_force_N"], r["peak_force_sd_N"]) == (93.3, 0.2)
    assert _row(b, afterload_mmHg=60)["efficiency"] == 0.246
    # Dynamic SV exceeds static SV at every afterload (Sec. III-D).
    assert np.all(b["dynamic_sv_ml"] > b["static_sv_ml"])


def test_fem_comparisons(paper):
    f = paper.fem_comparisons
    q = list(f["quantity"])
    eff = {
        float(o): v
        for qq, o, v in zip(q, f["omega"], f["value"], strict=True)
        if qq == "efficiency"
    }
    assert eff == {4.0: 0.442, 0.0: 0.331}
    by_q = {qq: i for i, qq in enumerate(q) if qq != "efficiency" and qq != "volume_drop_percent"}
    assert f["value"][by_q["mechanical_work_ratio"]] == 2.8
    assert f["value"][by_q["hydraulic_work_ratio"]] == 3.7
    for i in by_q.values():  # the ratios compare Omega 4 with Omega 0: no single omega
        assert math.isnan(f["omega"][i]) and f["shortening"][i] == 0.4
    drops = [f.row(i) for i, qq in enumerate(q) if qq == "volume_drop_percent"]
    assert sorted(r["value"] for r in drops) == [12.0, 42.0]
    for r in drops:
        assert r["unit"] == "%" and "1 J" in r["condition"] and math.isnan(r["shortening"])
    # e_helical / e_longitudinal = H ratio / M ratio, to the digits printed.
    assert abs(0.442 / 0.331 - 3.7 / 2.8) < 0.05


@pytest.mark.skipif(
    not PAPER.exists(),
    reason=f"the paper's text is not at {PAPER} (laid beside the repository as "
    "../shared/paper/soft-pump-paper.txt): the CSVs are not checked against it here",
)
def test_tables_match_paper_text(paper):
    """Re-read Tables I and II from the paper's text and compare every cell; find Fig. 10's
    numbers and the FEM comparisons, as transcribed, in its sentences."""
    lines = PAPER.read_text(encoding="utf-8").splitlines()
    start1 = lines.index("FEM PARAMETRIC STUDY")
    start2 = lines.index("EXPERIMENTAL VALIDATION")

    def cells(start, pattern):
        out = {}
        for line in lines[start + 3 : start + 8]:
            c = float(re.search(r"C = ([\d.]+)", line).group(1))
            for om, cell in enumerate(line.split("\t")[1:], start=1):
                if cell.strip():
                    out[(float(om), c)] = tuple(
                        float(x) for x in re.fullmatch(pattern, cell).groups()
                    )
        return out

    t1 = cells(start1, r"([\d.]+) \((\d)\)")
    t2 = cells(start2, r"([\d.]+) \((\d)\) ([\d.]+)")
    d1, d2 = paper.table1_fem, paper.table2_experiment
    assert t1 == {
        (o, c): (e, float(f))
        for o, c, e, f in zip(
            d1["omega"], d1["shortening"], d1["ef_percent"], d1["folds"], strict=True
        )
    }
    assert t2 == {
        (o, c): (e, float(f), err)
        for o, c, e, f, err in zip(
            d2["omega"],
            d2["shortening"],
            d2["ef_percent"],
            d2["folds"],
            d2["error_ml"],
            strict=True,
        )
    }
    text = PAPER.read_text(encoding="utf-8")
    b = paper.fig10_bench
    for s, sd in zip(b["static_sv_ml"], b["static_sv_sd_ml"], strict=True):
        assert f"{s} ± {sd} ml" in text
    for s, sd in zip(b["dynamic_sv_ml"], b["dynamic_sv_sd_ml"], strict=True):
        assert f"{s} ± {sd} ml" in text
    for s, sd in zip(b["peak_force_N"], b["peak_force_sd_N"], strict=True):
        assert f"{s} ± {sd} N" in text
    assert "0.168, 0.246, and 0.301" in text
    # the FEM comparisons: each value as the paper prints it, in the sentence the CSV cites
    f = paper.fem_comparisons
    printed = {
        "efficiency": "$e = {:g}$",
        "mechanical_work_ratio": "is {:g} times higher",
        "hydraulic_work_ratio": "becomes {:g} times",
        "volume_drop_percent": "{:g}%",
    }
    for quantity, value in zip(f["quantity"], f["value"], strict=True):
        assert printed[quantity].format(value) in text, (quantity, value)


def test_load_is_pure_numpy():
    # ``import cardiosoft`` brings in JAX (its public names re-export the model), so the module
    # is run from its file alone: it needs neither JAX nor the rest of cardiosoft.
    import subprocess
    import sys

    code = (
        "import importlib.util, sys; "
        f"spec = importlib.util.spec_from_file_location('datasets', {str(datasets.__file__)!r}); "
        "m = sys.modules['datasets'] = importlib.util.module_from_spec(spec); "
        "spec.loader.exec_module(m); "
        f"m.load_paper_data({str(DATA)!r}); "
        "sys.exit(int('jax' in sys.modules) + 2 * int('cardiosoft' in sys.modules))"
    )
    assert subprocess.run([sys.executable, "-c", code], check=False).returncode == 0


def test_arrays_are_read_only(paper):
    with pytest.raises(ValueError):
        paper.table1_fem["ef_percent"][0] = 1.0
    with pytest.raises(TypeError):
        paper.table1_fem.columns["x"] = np.zeros(1)


# ---------------------------------------------------------------- bring your own file

HEADER1 = "omega,shortening,ef_percent,folds,provenance"


def _write(tmp_path, name, *lines):
    path = tmp_path / name
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def test_own_sweep_by_name_and_by_kind(tmp_path):
    p = _write(
        tmp_path,
        "table1_fem_mysweep.csv",
        "# my sweep",
        HEADER1,
        "6,0.45,80.1,4,my FEM run 2024-03",
        "0,0.4,15,4,my FEM run 2024-03",
    )
    d = load(p)
    assert d.kind == "table1_fem" and len(d) == 2 and d.lines == (3, 4)
    q = tmp_path / "whatever.csv"
    q.write_bytes(p.read_bytes())
    with pytest.raises(ValueError, match=r"whatever\.csv.*cannot infer the dataset kind"):
        load(q)
    assert load(q, kind="table1_fem").sha256 == d.sha256
    with pytest.raises(ValueError, match="unknown dataset kind 'table9'"):
        load(q, kind="table9")
    # folds is optional in an FEM sweep.
    d = load(
        _write(tmp_path, "t.csv", "omega,shortening,ef_percent,provenance", "3,0.4,70,x"),
        kind="table1_fem",
    )
    assert "folds" not in d


def test_own_bench_rows(tmp_path):
    p = _write(
        tmp_path,
        "fig10_bench_rig2.csv",
        "afterload_mmHg,dynamic_sv_ml,omega,shortening,provenance",
        "45,70.0,4,0.4,rig 2",
        "75,65.0,4,0.4,rig 2",
    )
    d = load(p)
    assert d.kind == "fig10_bench" and "static_sv_ml" not in d
    np.testing.assert_array_equal(d["dynamic_sv_ml"], [70.0, 65.0])


def _refused(path, *, line, column, kind=None, match=""):
    with pytest.raises(ValueError) as info:
        load(path, kind=kind)
    msg = str(info.value)
    assert str(path) in msg, msg
    assert f"line {line}" in msg, msg
    assert f"column '{column}'" in msg, msg
    assert re.search(match, msg), msg
    return msg


@pytest.mark.parametrize(
    ("lines", "line", "column", "match"),
    [
        # missing / unknown / repeated column: reported on the header line
        (["omega,shortening,folds,provenance", "1,0.2,4,x"], 1, "ef_percent", "missing"),
        ([HEADER1 + ",pressure_mmHg", "1,0.2,30,4,x,0"], 1, "pressure_mmHg", "unknown column"),
        (["omega,omega,shortening,ef_percent,provenance", "1,1,0.2,30,x"], 1, "omega", "twice"),
        # non-numeric and non-finite values
        ([HEADER1, "1,0.2,30,4,x", "2,0.2,thirty,4,x"], 3, "ef_percent", "not a number"),
        ([HEADER1, "1,0.2,nan,4,x"], 2, "ef_percent", "not a finite number"),
        ([HEADER1, "1,0.2,inf,4,x"], 2, "ef_percent", "not a finite number"),
        # ranges
        ([HEADER1, "1,1.0,30,4,x"], 2, "shortening", r"outside the allowed range \[0, 1\)"),
        ([HEADER1, "1,-0.1,30,4,x"], 2, "shortening", "outside the allowed range"),
        ([HEADER1, "1,0.2,100.5,4,x"], 2, "ef_percent", r"\[0, 100\] %"),
        ([HEADER1, "1,0.2,-1,4,x"], 2, "ef_percent", "outside the allowed range"),
        ([HEADER1, "-1,0.2,30,4,x"], 2, "omega", "outside the allowed range"),
        ([HEADER1, "1,0.2,30,0,x"], 2, "folds", r"outside the allowed range \[1, inf\)"),
        ([HEADER1, "1,0.2,30,-3,x"], 2, "folds", "outside the allowed range"),
        ([HEADER1, "1,0.2,30,3.5,x"], 2, "folds", "not an integer"),
        ([HEADER1, "1,0.2,30,,x"], 2, "folds", "empty cell"),
        # provenance
        ([HEADER1, "1,0.2,30,4,"], 2, "provenance", "empty provenance"),
        ([HEADER1, "1,0.2,30,4,   "], 2, "provenance", "empty provenance"),
        # duplicate key, with comments and a blank line counted in the line number
        (
            ["# a sweep", HEADER1, "1,0.2,30,4,x", "", "1.0,0.20,31,4,y"],
            5,
            "omega,shortening",
            "duplicate row.*same key as line 3",
        ),
    ],
)
def test_table1_refusals(tmp_path, lines, line, column, match):
    path = _write(tmp_path, "table1_fem_bad.csv", *lines)
    _refused(path, line=line, column=column, match=match)


def test_accepts_integral_float_folds(tmp_path):
    d = load(_write(tmp_path, "table1_fem_ok.csv", HEADER1, "1,0.2,30,4.0,x"))
    assert d["folds"].tolist() == [4]


def test_wrong_cell_count_and_empty_files(tmp_path):
    p = _write(tmp_path, "table1_fem_short.csv", HEADER1, "1,0.2,30,x")
    with pytest.raises(ValueError, match=r"table1_fem_short\.csv, line 2 \(data row 1\).*4 cells"):
        load(p)
    p = _write(tmp_path, "table1_fem_empty.csv", "# nothing")
    with pytest.raises(ValueError, match=r"table1_fem_empty\.csv.*no header"):
        load(p)
    p = _write(tmp_path, "table1_fem_nodata.csv", HEADER1)
    with pytest.raises(ValueError, match=r"table1_fem_nodata\.csv, line 1 \(header\).*no data"):
        load(p)


HEADER2 = "omega,shortening,ef_percent,folds,error_ml,provenance"


@pytest.mark.parametrize(
    ("row", "column", "match"),
    [
        ("1,0.4,58.3,3,-3.7,Table II", "error_ml", "outside the allowed range"),
        ("1,0.4,58.3,3,abc,Table II", "error_ml", "not a number"),
        ("1,0.4,58.3,,3.7,Table II", "folds", "empty cell"),
        ("1,0.4,58.3,3,3.7,", "provenance", "empty provenance"),
    ],
)
def test_table2_refusals(tmp_path, row, column, match):
    path = _write(tmp_path, "table2_experiment_x.csv", HEADER2, "2,0.4,67.0,4,1.9,Table II", row)
    _refused(path, line=3, column=column, match=match)


def test_table2_duplicate(tmp_path):
    path = _write(tmp_path, "t2.csv", HEADER2, "2,0.4,67.0,4,1.9,a", "2,0.4,67.5,4,1.9,b")
    _refused(path, kind="table2_experiment", line=3, column="omega,shortening", match="duplicate")


HEADER10 = (
    "afterload_mmHg,static_sv_ml,static_sv_sd_ml,dynamic_sv_ml,peak_force_N,efficiency,"
    "omega,shortening,bpm,provenance"
)


@pytest.mark.parametrize(
    ("row", "column", "match"),
    [
        ("-30,67.8,2.6,71.3,54.4,0.168,4,0.4,30,x", "afterload_mmHg", "outside.*mmHg"),
        ("30,67.8,-2.6,71.3,54.4,0.168,4,0.4,30,x", "static_sv_sd_ml", "outside"),
        ("30,67.8,2.6,71.3,54.4,1.2,4,0.4,30,x", "efficiency", r"\[0, 1\]"),
        ("30,67.8,2.6,71.3,54.4,0.168,4,0.4,0,x", "bpm", r"\(0, inf\)"),
        ("30,,2.6,71.3,54.4,0.168,4,0.4,30,x", "static_sv_sd_ml", "its mean 'static_sv_ml'"),
        (
            "30,,,,,,4,0.4,30,x",
            "static_sv_ml|dynamic_sv_ml|peak_force_N|efficiency",
            "none of these",
        ),
        ("30,67.8,2.6,71.3,54.4,0.168,4,0.4,30,", "provenance", "empty provenance"),
        (
            "90,55.7,1.2,66.9,93.3,0.301,4,0.4,30,y",
            "omega,shortening,afterload_mmHg,bpm",
            "duplicate",
        ),
    ],
)
def test_fig10_refusals(tmp_path, row, column, match):
    path = _write(
        tmp_path, "fig10_bench_x.csv", HEADER10, "90,55.7,1.2,66.9,93.3,0.301,4,0.4,30,x", row
    )
    _refused(path, line=3, column=column, match=match)


HEADERC = "quantity,omega,shortening,value,unit,condition,provenance"


@pytest.mark.parametrize(
    ("row", "column", "match"),
    [
        ("efficiency,4,0.4,1.4,-,,x", "value", r"outside.*for efficiency"),
        ("volume_drop_percent,,,42,-,,x", "unit", "is in '%'"),
        ("volume_drop_percent,,,142,%,,x", "value", "outside"),
        ("mechanical_work_ratio,,0.4,0,-,,x", "value", r"\(0, inf\)"),
        ("power,4,0.4,1,-,,x", "quantity", "not one of"),
        ("efficiency,4,0.4,0.4,kg,,x", "unit", "not one of"),
        ("efficiency,4,0.4,,-,,x", "value", "empty cell"),
        ("efficiency,4,0.4,0.5,-,,", "provenance", "empty provenance"),
        ("efficiency,0,0.4,0.3,-,,y", "quantity,omega,shortening,condition", "duplicate"),
    ],
)
def test_fem_comparisons_refusals(tmp_path, row, column, match):
    path = _write(tmp_path, "fem_comparisons_x.csv", HEADERC, "efficiency,0,0.4,0.331,-,,x", row)
    _refused(path, line=3, column=column, match=match)


def test_fem_comparisons_empty_cells_compare_equal_in_key(tmp_path):
    path = _write(
        tmp_path,
        "fem_comparisons_x.csv",
        HEADERC,
        "volume_drop_percent,,,42,%,E = 1 J,x",
        "volume_drop_percent,,,43,%,E = 1 J,y",
    )
    _refused(path, line=3, column="quantity,omega,shortening,condition", match="duplicate")


def test_sha256_changes_with_content(tmp_path):
    a = _write(tmp_path, "a.csv", "x")
    b = _write(tmp_path, "b.csv", "y")
    assert sha256(a) != sha256(b)
    assert sha256(a) == "73cb3858a687a8494ca3323053016282f3dad39d42cf62ca4e79dda2aac7d9ac"


def test_readme_documents_every_column():
    readme = (DATA / "README.md").read_text(encoding="utf-8")
    for kind, schema in datasets.SCHEMAS.items():
        assert f"### `{kind}`" in readme
        for name in schema.columns:
            assert f"`{name}`" in readme, (kind, name)
