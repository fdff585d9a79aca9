"""The paper's numbers as validated CSV files, and a strict loader for files of the same kinds.

Five kinds of file live in ``fit/data/`` (schema and conventions in ``fit/data/README.md``),
shipped inside the package as ``cardiosoft/_paper_data`` (:func:`default_root`):

- ``table1_fem``: FEM sweep of EF (and folds) over Omega x C at zero pressure (Table I);
- ``table2_experiment``: experimental EF, folds and FEM error (Table II, held out for validation);
- ``fig10_bench``: the ventricle-simulator bench at 30/60/90 mmHg (Sec. III-D, Fig. 10);
- ``fem_comparisons``: scalar FEM comparisons of helical vs longitudinal loading (Sec. III-A, C);
- ``membrane_inflation``: the shell's swelling V(P) at zero cable pull, *computed* (not
  transcribed) from the paper's geometry and material by ``python -m fit.membrane``.

A researcher can bring a file of any of these kinds: ``load(path)`` infers the kind from a file
name that starts with the kind (``table1_fem_mysweep.csv``), or ``load(path, kind="table1_fem")``
takes any name. A malformed file is refused with a ``ValueError`` that names the file, the line
(1-based physical line of the file, counting comment lines and the header; the data-row number
is given too) and the column, so that the message can be printed as it is.

Pure Python + numpy: no JAX here, so the data can be read and checked without the model.
"""

from __future__ import annotations

import csv
import hashlib
import math
import types
from collections.abc import Mapping
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

__all__ = [
    "KINDS",
    "SCHEMAS",
    "Column",
    "Dataset",
    "PaperData",
    "default_root",
    "infer_kind",
    "load",
    "load_paper_data",
]


@dataclass(frozen=True)
class Column:
    """One column of a schema.

    ``dtype`` is ``"float"``, ``"int"`` (an integral value; ``4`` and ``4.0`` are accepted,
    ``3.5`` is not) or ``"str"``. Numbers must be finite and lie in ``[lo, hi]`` (an end is open
    when ``lo_open``/``hi_open``). ``required``: the column must be in the header. ``nullable``:
    a cell may be empty (read as NaN for ``float``; ``int`` columns are never nullable).
    ``choices``: the allowed values of a ``str`` column (``None``: any non-empty text).
    ``needs``: another column whose cell must be non-empty whenever this one is (an SD needs its
    mean).
    """

    dtype: str
    unit: str = "-"
    lo: float = -math.inf
    hi: float = math.inf
    lo_open: bool = False
    hi_open: bool = False
    required: bool = True
    nullable: bool = False
    choices: tuple[str, ...] | None = None
    needs: str | None = None
    doc: str = ""

    def range_text(self) -> str:
        left = "(" if self.lo_open else "["
        right = ")" if self.hi_open or math.isinf(self.hi) else "]"
        return f"{left}{_fmt(self.lo)}, {_fmt(self.hi)}{right}"


@dataclass(frozen=True)
class Schema:
    """The columns of one kind, the key columns that must be unique, and a one-line summary.

    ``at_least_one``: columns of which each row must give at least one value (a bench row with
    no measurement is refused).
    """

    kind: str
    columns: Mapping[str, Column]
    key: tuple[str, ...]
    doc: str = ""
    at_least_one: tuple[str, ...] = ()


def _fmt(v: float) -> str:
    return f"{v:.6g}"


_INF = math.inf

_OMEGA = Column(
    "float", "-", 0.0, 50.0, doc="helix parameter Omega (n = Omega/4 turns); 0 = longitudinal"
)
_SHORTENING = Column("float", "-", 0.0, 1.0, hi_open=True, doc="cable shortening C = x / L")
_EF = Column("float", "%", 0.0, 100.0, doc="ejection fraction (1 - V_c/V_u) * 100 at zero pressure")
_FOLDS = Column("int", "-", 1.0, _INF, doc="number of folds of the contracted shell")


def _optional(unit: str, doc: str, needs: str | None = None) -> Column:
    """An optional, nullable, non-negative float column (a bench measurement or its SD)."""
    return Column("float", unit, 0.0, _INF, required=False, nullable=True, needs=needs, doc=doc)


_PROVENANCE = Column("str", doc="where the numbers of the row come from (table, figure, sentence)")

SCHEMAS: dict[str, Schema] = {
    "table1_fem": Schema(
        "table1_fem",
        {
            "omega": _OMEGA,
            "shortening": _SHORTENING,
            "ef_percent": _EF,
            "folds": Column(
                "int", "-", 1.0, _INF, required=False, doc=_FOLDS.doc + " (optional column)"
            ),
            "provenance": _PROVENANCE,
        },
        key=("omega", "shortening"),
        doc="FEM sweep at zero pressure: EF (and folds) over Omega x C (paper: Table I)",
    ),
    "table2_experiment": Schema(
        "table2_experiment",
        {
            "omega": _OMEGA,
            "shortening": _SHORTENING,
            "ef_percent": _EF,
            "folds": _FOLDS,
            "error_ml": _optional(
                "ml", "absolute FEM-vs-experiment error of the contracted inner volume"
            ),
            "provenance": _PROVENANCE,
        },
        key=("omega", "shortening"),
        doc="experiments at zero pressure: EF, folds, FEM error (paper: Table II, held out)",
    ),
    "fig10_bench": Schema(
        "fig10_bench",
        {
            "afterload_mmHg": Column("float", "mmHg", 0.0, _INF, doc="water-column afterload"),
            "static_sv_ml": _optional("ml", "static stroke volume (mean)"),
            "static_sv_sd_ml": _optional("ml", "its standard deviation", needs="static_sv_ml"),
            "dynamic_sv_ml": _optional("ml", "dynamic (peak) stroke volume (mean)"),
            "dynamic_sv_sd_ml": _optional("ml", "its standard deviation", needs="dynamic_sv_ml"),
            "peak_force_N": _optional("N", "peak total cable force (mean)"),
            "peak_force_sd_N": _optional("N", "its standard deviation", needs="peak_force_N"),
            "efficiency": Column(
                "float",
                "-",
                0.0,
                1.0,
                required=False,
                nullable=True,
                doc="e = H / M = P_a * SV / M",
            ),
            "omega": _OMEGA,
            "shortening": _SHORTENING,
            "bpm": Column(
                "float",
                "1/min",
                0.0,
                _INF,
                lo_open=True,
                required=False,
                nullable=True,
                doc="beat rate of the dynamic tests",
            ),
            "provenance": _PROVENANCE,
        },
        key=("omega", "shortening", "afterload_mmHg", "bpm"),
        doc="bench rows at a given afterload: SVs, peak force, efficiency (paper: Fig. 10)",
        at_least_one=("static_sv_ml", "dynamic_sv_ml", "peak_force_N", "efficiency"),
    ),
    "fem_comparisons": Schema(
        "fem_comparisons",
        {
            "quantity": Column(
                "str",
                choices=(
                    "efficiency",
                    "mechanical_work_ratio",
                    "hydraulic_work_ratio",
                    "volume_drop_percent",
                ),
                doc="what value is",
            ),
            "omega": Column(
                "float", "-", 0.0, 50.0, nullable=True, doc=_OMEGA.doc + "; empty: n/a or unknown"
            ),
            "shortening": Column(
                "float",
                "-",
                0.0,
                1.0,
                hi_open=True,
                nullable=True,
                doc=_SHORTENING.doc + "; empty: n/a or unknown",
            ),
            "value": Column("float", doc="the number (range depends on quantity)"),
            "unit": Column("str", choices=("-", "%"), doc="'-' dimensionless, '%' percent"),
            "condition": Column(
                "str", required=False, nullable=True, doc="load case in words (free text)"
            ),
            "provenance": _PROVENANCE,
        },
        key=("quantity", "omega", "shortening", "condition"),
        doc="scalar FEM comparisons helical vs longitudinal (paper: Sec. III-A, III-C)",
    ),
    "membrane_inflation": Schema(
        "membrane_inflation",
        {
            "pressure_mmHg": Column(
                "float", "mmHg", 0.0, _INF, doc="cavity pressure, zero cable pull"
            ),
            "volume_ml": Column("float", "ml", 0.0, _INF, lo_open=True, doc="cavity volume"),
            "swelling_ml": Column(
                "float", "ml", required=False, doc="volume minus the volume at zero pressure"
            ),
            "compliance_ml_per_mmHg": Column(
                "float",
                "ml/mmHg",
                0.0,
                _INF,
                lo_open=True,
                required=False,
                doc="tangent dV/dP of the curve",
            ),
            "plug_displacement_mm": Column(
                "float", "mm", required=False, doc="axial motion of the apex plug, + from the base"
            ),
            "max_stretch": Column(
                "float", "-", 1.0, _INF, required=False, doc="largest principal stretch of the wall"
            ),
            "provenance": _PROVENANCE,
        },
        key=("pressure_mmHg",),
        doc="the shell's V(P) at zero pull (computed from Sec. II-B, II-D by fit/membrane.py)",
    ),
}

KINDS: tuple[str, ...] = tuple(SCHEMAS)

# fem_comparisons: per-quantity range and unit of `value`.
_QUANTITY_RULES: dict[str, tuple[str, float, float, bool]] = {
    # quantity: (unit, lo, hi, lo_open)
    "efficiency": ("-", 0.0, 1.0, False),
    "mechanical_work_ratio": ("-", 0.0, _INF, True),
    "hydraulic_work_ratio": ("-", 0.0, _INF, True),
    "volume_drop_percent": ("%", 0.0, 100.0, False),
}

PAPER_FILES: dict[str, str] = {kind: f"{kind}.csv" for kind in KINDS}


@dataclass(frozen=True)
class Dataset:
    """A loaded, validated file.

    ``columns`` maps each column present in the file (except ``provenance``) to a read-only
    numpy array (``float64``; ``int64`` for ``int`` columns; ``object`` of ``str`` for text
    columns; NaN or ``""`` for empty nullable cells). ``provenance`` has one entry per row.
    ``lines`` gives the 1-based file line of each row (for messages downstream).
    """

    kind: str
    path: Path
    columns: Mapping[str, np.ndarray]
    provenance: tuple[str, ...]
    lines: tuple[int, ...]
    sha256: str

    def __getitem__(self, name: str) -> np.ndarray:
        try:
            return self.columns[name]
        except KeyError:
            raise KeyError(
                f"{self.path.name} ({self.kind}) has no column {name!r}; it has "
                f"{sorted(self.columns)}"
            ) from None

    def __contains__(self, name: object) -> bool:
        return name in self.columns

    def __len__(self) -> int:
        return len(self.provenance)

    def row(self, i: int) -> dict[str, object]:
        """Row ``i`` (0-based) as a dict, provenance included."""
        out = {
            name: arr[i] if arr.dtype == object else arr[i].item()
            for name, arr in self.columns.items()
        }
        out["provenance"] = self.provenance[i]
        return out


@dataclass(frozen=True)
class PaperData:
    """The five shipped files of ``fit/data`` (``membrane_inflation`` is computed, not
    transcribed: see ``fit/membrane.py``)."""

    table1_fem: Dataset
    table2_experiment: Dataset
    fig10_bench: Dataset
    fem_comparisons: Dataset
    membrane_inflation: Dataset

    def __iter__(self):
        return iter(
            (
                self.table1_fem,
                self.table2_experiment,
                self.fig10_bench,
                self.fem_comparisons,
                self.membrane_inflation,
            )
        )

    def hashes(self) -> dict[str, str]:
        """File name -> sha256, for the model card."""
        return {d.path.name: d.sha256 for d in self}


def infer_kind(path) -> str:
    """The kind whose name the file's stem equals or starts with (followed by ``_`` or ``-``)."""
    stem = Path(path).stem
    for kind in KINDS:
        if stem == kind or stem.startswith((kind + "_", kind + "-")):
            return kind
    raise ValueError(
        f"{Path(path)}: cannot infer the dataset kind from the file name {Path(path).name!r}; "
        f"name it after one of {list(KINDS)} (e.g. 'table1_fem_mysweep.csv') or pass "
        f"kind=... explicitly"
    )


def default_root() -> Path:
    """The folder of the shipped paper data, after an editable or a regular install.

    A regular install ships ``fit/data`` as the package data ``cardiosoft/_paper_data``; an
    editable install or a source checkout reads ``fit/data`` of the repository itself.
    """
    packaged = resources.files("cardiosoft") / "_paper_data"
    if packaged.is_dir():
        return Path(str(packaged))
    root = Path(__file__).resolve().parent.parent / "fit" / "data"
    if not root.is_dir():
        raise FileNotFoundError(
            f"no paper data found: expected the package data cardiosoft/_paper_data or {root} "
            f"in a source checkout; pass root=... pointing at a directory with "
            f"{sorted(PAPER_FILES.values())}"
        )
    return root


def load_paper_data(root=None) -> PaperData:
    """Load and validate the five shipped files from ``root`` (default: :func:`default_root`)."""
    root = default_root() if root is None else Path(root)
    return PaperData(**{kind: load(root / name, kind) for kind, name in PAPER_FILES.items()})


class _Where:
    """Builds the 'file, line, column' prefix of every refusal."""

    def __init__(self, path: Path, kind: str):
        self.path = path
        self.kind = kind

    def err(self, line: int | None, row: int | None, column: str | None, what: str):
        parts = [str(self.path)]
        if line is not None:
            parts.append(f"line {line}" + (" (header)" if row is None else f" (data row {row})"))
        if column is not None:
            parts.append(f"column {column!r}")
        return ValueError(", ".join(parts) + f": {what} [kind {self.kind}]")


def _parse_number(text: str, col: Column, name: str, where: _Where, line: int, row: int):
    try:
        v = float(text)
    except ValueError:
        raise where.err(line, row, name, f"{text!r} is not a number") from None
    if not math.isfinite(v):
        raise where.err(line, row, name, f"{text!r} is not a finite number")
    unit = f" {col.unit}" if col.unit not in ("-", "") else ""
    if col.dtype == "int" and v != int(v):
        raise where.err(line, row, name, f"{text!r} is not an integer")
    below = v <= col.lo if col.lo_open else v < col.lo
    above = v >= col.hi if col.hi_open else v > col.hi
    if below or above:
        raise where.err(
            line,
            row,
            name,
            f"{_fmt(v)}{unit} is outside the allowed range {col.range_text()}{unit}",
        )
    return int(v) if col.dtype == "int" else v


def load(path, kind: str | None = None) -> Dataset:
    """Read and validate a CSV file of one of the :data:`KINDS`; refuse it with a ``ValueError``.

    ``kind`` defaults to :func:`infer_kind` of the file name. Lines whose first character is
    ``#`` are comments; blank lines are skipped. Cells are stripped of surrounding spaces. The
    message of a refusal names the file, the 1-based file line (the data-row number too) and the
    column: missing or unknown or repeated column, wrong number of cells, empty cell in a
    non-nullable column, non-numeric or non-finite value, non-integer where an integer is due,
    value out of range, text not among the allowed choices, empty provenance, an SD without its
    mean, and two rows with the same key (e.g. the same ``(omega, shortening)``).
    """
    path = Path(path)
    if kind is None:
        kind = infer_kind(path)
    if kind not in SCHEMAS:
        raise ValueError(f"{path}: unknown dataset kind {kind!r}; known kinds: {list(KINDS)}")
    schema = SCHEMAS[kind]
    where = _Where(path, kind)

    raw = path.read_bytes()
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        raise where.err(None, None, None, f"not UTF-8 text ({e})") from None
    records = []  # (line number, cells)
    reader = csv.reader(text.splitlines(keepends=True))
    for cells in reader:
        line = reader.line_num
        if not cells or all(not c.strip() for c in cells):
            continue
        if cells[0].lstrip().startswith("#"):
            continue
        records.append((line, [c.strip() for c in cells]))
    if not records:
        raise where.err(None, None, None, "no header line (the file is empty or all comments)")

    header_line, header = records[0]
    seen = set()
    for name in header:
        if name in seen:
            raise where.err(header_line, None, name, "the column appears twice in the header")
        seen.add(name)
        if name not in schema.columns:
            raise where.err(
                header_line,
                None,
                name,
                f"unknown column; the columns of {kind} are {list(schema.columns)}",
            )
    for name, col in schema.columns.items():
        if col.required and name not in seen:
            raise where.err(header_line, None, name, "required column is missing from the header")
    if schema.at_least_one and not seen.intersection(schema.at_least_one):
        raise where.err(
            header_line,
            None,
            "|".join(schema.at_least_one),
            "the header has none of these measurement columns",
        )
    data = records[1:]
    if not data:
        raise where.err(header_line, None, None, "no data rows after the header")

    values: dict[str, list] = {name: [] for name in header}
    lines: list[int] = []
    keys: dict[tuple, int] = {}
    for row, (line, cells) in enumerate(data, start=1):
        if len(cells) != len(header):
            raise where.err(
                line,
                row,
                None,
                f"{len(cells)} cells where the header has {len(header)} columns",
            )
        parsed: dict[str, object] = {}
        for name, cell in zip(header, cells, strict=True):
            col = schema.columns[name]
            if cell == "":
                if not col.nullable:
                    what = (
                        "empty provenance: say where the numbers come from"
                        if name == "provenance"
                        else "empty cell in a column that needs a value"
                    )
                    raise where.err(line, row, name, what)
                parsed[name] = math.nan if col.dtype == "float" else ""
                continue
            if col.dtype == "str":
                if col.choices is not None and cell not in col.choices:
                    raise where.err(line, row, name, f"{cell!r} is not one of {list(col.choices)}")
                parsed[name] = cell
            else:
                parsed[name] = _parse_number(cell, col, name, where, line, row)
        for name, col in schema.columns.items():
            if col.needs and name in parsed and not _empty(parsed[name]):
                if col.needs not in parsed or _empty(parsed[col.needs]):
                    raise where.err(
                        line, row, name, f"a value is given but its mean {col.needs!r} is not"
                    )
        if schema.at_least_one and all(_empty(parsed.get(k, "")) for k in schema.at_least_one):
            raise where.err(
                line, row, "|".join(schema.at_least_one), "the row gives none of these values"
            )
        if kind == "fem_comparisons":
            _check_quantity(parsed, where, line, row)
        key = tuple(_key_part(parsed.get(k)) for k in schema.key)
        if key in keys:
            shown = ", ".join(f"{k}={parsed.get(k, '')!s}" for k in schema.key if k in parsed)
            raise where.err(
                line,
                row,
                ",".join(k for k in schema.key if k in parsed),
                f"duplicate row ({shown}): same key as line {keys[key]}",
            )
        keys[key] = line
        lines.append(line)
        for name in header:
            values[name].append(parsed[name])

    columns = {}
    for name in header:
        if name == "provenance":
            continue
        dtype = {"float": np.float64, "int": np.int64, "str": object}[schema.columns[name].dtype]
        arr = np.array(values[name], dtype=dtype)
        arr.setflags(write=False)
        columns[name] = arr
    return Dataset(
        kind=kind,
        path=path,
        columns=types.MappingProxyType(columns),
        provenance=tuple(values["provenance"]),
        lines=tuple(lines),
        sha256=hashlib.sha256(raw).hexdigest(),
    )


def _empty(v) -> bool:
    return v == "" or (isinstance(v, float) and math.isnan(v))


def _key_part(v):
    # NaN != NaN: empty cells compare equal to each other through None.
    return None if v is None or _empty(v) else v


def _check_quantity(parsed: dict, where: _Where, line: int, row: int) -> None:
    q = parsed["quantity"]
    unit, lo, hi, lo_open = _QUANTITY_RULES[q]
    if parsed["unit"] != unit:
        raise where.err(line, row, "unit", f"{q} is in {unit!r}, not {parsed['unit']!r}")
    v = parsed["value"]
    if (v <= lo if lo_open else v < lo) or v > hi:
        left = "(" if lo_open else "["
        right = ")" if math.isinf(hi) else "]"
        raise where.err(
            line,
            row,
            "value",
            f"{_fmt(v)} is outside the allowed range {left}{_fmt(lo)}, {_fmt(hi)}{right} for {q}",
        )
