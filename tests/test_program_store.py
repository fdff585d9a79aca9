"""The store of exported programs (issue #41, ``cardiosoft.program_store``): a later process loads
a program instead of tracing it, gets the traced program's results, and never trusts a stale,
foreign or corrupt entry."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cardiosoft import program_store
from cardiosoft.program_store import (
    SHIPPED,
    prune,
    read_header,
    sources_digest,
    stored_call,
    stored_value,
    use_program_store,
)  # fmt: skip

ROOT = Path(__file__).resolve().parent.parent
TRACED = []  # one entry each time the function below is traced


@eqx.filter_jit
def _beat_like(numbers: dict, scale: float):
    """A stand-in of a batch solve: arrays and a static number in, a dict with None, a tuple
    and diffrax's result code (an equinox module with a static field) out."""
    TRACED.append(scale)
    y = numbers["a"] * scale + numbers["b"]
    results = diffrax.RESULTS
    code = results.where(y[0] > 0, results.successful, results.max_steps_reached)
    return {"y": y, "none": None, "pair": (jnp.sum(y), code)}


NUMBERS = {"a": jnp.arange(3.0), "b": jnp.ones(3)}


@pytest.fixture
def store(tmp_path):
    use_program_store(tmp_path)
    TRACED.clear()
    yield tmp_path
    use_program_store(None)


def _entry(folder: Path) -> Path:
    (path,) = folder.glob("*.jaxprogram")
    return path


def test_a_stored_program_is_loaded_without_tracing(store):
    out = stored_call(_beat_like, NUMBERS, 2.0)
    np.testing.assert_array_equal(out["y"], [1.0, 3.0, 5.0])
    assert out["none"] is None and out["pair"][1] == diffrax.RESULTS.successful
    assert TRACED == [2.0] and _entry(store).exists()

    use_program_store(store)  # a new process: nothing loaded yet
    again = stored_call(_beat_like, {"a": jnp.arange(3.0) + 1, "b": jnp.zeros(3)}, 2.0)
    assert TRACED == [2.0], "the stored program was traced again"
    np.testing.assert_array_equal(again["y"], [2.0, 4.0, 6.0])  # new numbers, same program
    assert float(again["pair"][0]) == 12.0


def test_another_static_argument_is_another_program(store):
    stored_call(_beat_like, NUMBERS, 2.0)
    stored_call(_beat_like, NUMBERS, 3.0)
    assert TRACED == [2.0, 3.0] and len(list(store.glob("*.jaxprogram"))) == 2


@pytest.mark.parametrize("damage", ["corrupt", "foreign", "truncated"])
def test_a_damaged_entry_is_rebuilt_not_trusted(store, damage):
    stored_call(_beat_like, NUMBERS, 2.0)
    path = _entry(store)
    raw = path.read_bytes()
    head, _, body = raw.partition(b"\n")
    if damage == "corrupt":  # one byte of the program flipped: the digest no longer matches
        body = body[:-100] + bytes([body[-100] ^ 0xFF]) + body[-99:]
        path.write_bytes(head + b"\n" + body)
    elif damage == "foreign":  # a valid entry of another key under this name
        header = json.loads(head)
        header["key"] = "0" * 64
        path.write_bytes(json.dumps(header).encode() + b"\n" + body)
    else:
        path.write_bytes(raw[: len(raw) // 2])
    use_program_store(store)
    out = stored_call(_beat_like, NUMBERS, 2.0)
    assert TRACED == [2.0, 2.0], "a damaged entry was used"
    np.testing.assert_array_equal(out["y"], [1.0, 3.0, 5.0])

    use_program_store(store)
    stored_call(_beat_like, NUMBERS, 2.0)
    assert TRACED == [2.0, 2.0], "the entry was not rewritten"  # the rebuilt one is loaded


def test_pruning_deletes_the_least_recently_used_entries(store, monkeypatch):
    written = []
    for age, scale in enumerate((2.0, 3.0, 4.0)):  # three entries, the first the oldest
        stored_call(_beat_like, NUMBERS, scale)
        (new,) = set(store.glob("*.jaxprogram")) - set(written)
        os.utime(new, (1e9 + age, 1e9 + age))
        written.append(new)
    use_program_store(store)  # a new process reads the oldest entry: it is used now
    stored_call(_beat_like, NUMBERS, 2.0)
    assert TRACED == [2.0, 3.0, 4.0], "the oldest entry was not loaded"
    kept = written[0].stat().st_size + written[2].stat().st_size
    deleted = prune(store, kept)  # room for two of the three
    assert deleted == [written[1]], "not the least recently used entry"
    assert sorted(store.glob("*.jaxprogram")) == sorted([written[0], written[2]])

    # a write prunes the store to its limit: here room for one entry (they differ by bytes)
    monkeypatch.setattr(program_store, "STORE_LIMIT_BYTES", written[0].stat().st_size + 64)
    stored_call(_beat_like, NUMBERS, 5.0)
    (left,) = store.glob("*.jaxprogram")
    assert left not in written, "the write did not prune the store"


def test_a_missing_entry_is_copied_from_the_shipped_programs_not_traced(store, tmp_path):
    """A fresh machine's store is empty: the package's program of the same key is copied into
    it and loaded; a damaged shipped entry is not trusted (the program is traced)."""
    shipped = store  # the package's programs, exported from these sources
    stored_call(_beat_like, NUMBERS, 2.0)
    (entry,) = shipped.glob("*.jaxprogram")
    fresh = tmp_path / "fresh"
    use_program_store(fresh, shipped)  # a new process on a fresh machine
    out = stored_call(_beat_like, {"a": jnp.arange(3.0) + 1, "b": jnp.zeros(3)}, 2.0)
    assert TRACED == [2.0], "the shipped program was traced again"
    np.testing.assert_array_equal(out["y"], [2.0, 4.0, 6.0])
    assert (fresh / entry.name).read_bytes() == entry.read_bytes()

    raw = bytearray(entry.read_bytes())
    raw[-50] ^= 0xFF  # one byte of the shipped program flipped
    entry.write_bytes(bytes(raw))
    use_program_store(tmp_path / "another", shipped)
    out = stored_call(_beat_like, NUMBERS, 2.0)
    assert TRACED == [2.0, 2.0], "a damaged shipped entry was used"
    np.testing.assert_array_equal(out["y"], [1.0, 3.0, 5.0])


def test_the_shipped_programs_were_exported_from_these_sources():
    """Every program shipped with the package was traced from cardiosoft's current sources:
    an edit makes them stale (unused, so a fresh machine traces again). If this fails, write
    them again: ``python tools/ship_programs.py`` (about 2 minutes)."""
    entries = sorted(SHIPPED.glob("*.jaxprogram"))
    assert entries, f"no programs shipped in {SHIPPED}"
    stale = [p.name for p in entries if read_header(p).get("sources") != sources_digest()]
    assert not stale, f"{len(stale)} of {len(entries)} shipped programs are stale: run " \
        "python tools/ship_programs.py"
    assert {read_header(p)["kind"] for p in entries} == {"program"}


def _value(store, numbers, calls):
    """A value kept in the store for ``numbers`` and a static part, counting its computations."""

    def compute():
        calls.append(1)
        return {"sum": float(jnp.sum(numbers))}

    return stored_value("a sum", (numbers, "its wiring"), compute, lambda v: v, lambda v: v)


def test_a_stored_value_is_computed_once_per_input_and_never_trusted_damaged(store):
    calls = []
    assert _value(store, jnp.arange(3.0), calls) == {"sum": 3.0} and calls == [1]
    use_program_store(store)  # a new process
    assert _value(store, jnp.arange(3.0), calls) == {"sum": 3.0} and calls == [1]
    assert _value(store, jnp.arange(3.0) + 1, calls) == {"sum": 6.0} and calls == [1, 1]
    for path in store.glob("*.jaxprogram"):  # one byte of each value flipped
        raw = bytearray(path.read_bytes())
        raw[-2] ^= 0xFF
        path.write_bytes(bytes(raw))
    use_program_store(store)
    assert _value(store, jnp.arange(3.0), calls) == {"sum": 3.0} and calls == [1, 1, 1]


def test_a_dict_of_arrays_is_kept_exactly_by_default(store):
    """stored_value's own codec (a design search's grid): every float64 to the last bit (NaN
    too), and each array's dtype and shape, read back by a new process."""
    value = {
        "x": np.array([0.1, 1 / 3, np.nan, -2.5e-300]), "ok": np.array([[True, False]]),
        "n": np.array([3, -1], dtype=np.int32),
    }  # fmt: skip
    calls = []

    def compute():
        calls.append(1)
        return value

    stored_value("arrays", (jnp.arange(2.0), "its wiring"), compute)
    use_program_store(store)  # a new process
    got = stored_value("arrays", (jnp.arange(2.0), "its wiring"), compute)
    assert calls == [1], "the value was computed again"
    np.testing.assert_array_equal(got["x"], value["x"])
    assert got["x"].dtype == np.float64
    assert got["ok"].dtype == bool and got["ok"].tolist() == [[True, False]]
    assert got["n"].dtype == np.int32 and got["n"].tolist() == [3, -1]


def test_an_svzerod_models_solving_order_is_read_back_not_found_again(store, monkeypatch):
    """Reading a model orders its nodes (cardiosoft.network.ordering); a later process reading
    the same model takes the stored order, equal to the one found."""
    from cardiosoft.network import ordering, read

    model = ROOT / "tests" / "data" / "svzerod" / "closedLoopHeart_singleVessel.json"
    found = read(model).network.order
    assert found is not None and len(list(store.glob("*.jaxprogram"))) == 1
    use_program_store(store)

    def not_again(*args, **kwargs):
        raise AssertionError("the solving order was found again")

    monkeypatch.setattr(ordering, "order_nodes", not_again)
    assert read(model).network.order == found


@eqx.filter_jit
def _with_host_callback(x):
    jax.debug.callback(lambda: TRACED.append("called back"))  # JAX cannot export this
    return 2 * x


def test_a_program_that_cannot_be_exported_is_traced_as_before(store):
    np.testing.assert_array_equal(stored_call(_with_host_callback, jnp.ones(2)), [2.0, 2.0])
    assert not list(store.glob("*.jaxprogram"))


def test_without_a_store_the_function_is_traced_as_usual():
    use_program_store(None)
    TRACED.clear()
    out = stored_call(_beat_like, NUMBERS, 5.0)
    np.testing.assert_array_equal(out["y"], [1.0, 6.0, 11.0])
    assert TRACED == [5.0]


def _fresh(tmp_path, name: str, cache: str, command: list[str], shipped: bool = False) -> Path:
    """``python -m cardiosoft.<command> --out tmp_path/name`` in a fresh process with the
    compile cache (and its program store) in ``cache`` ("0": none), the programs shipped with
    the package copied into the store or not."""
    out = tmp_path / name
    env = {"CARDIOSOFT_COMPILE_CACHE": cache, "CARDIOSOFT_SHIPPED_PROGRAMS": str(int(shipped))}
    subprocess.run(
        [sys.executable, "-m", *command, "--quiet", "--no-plot", "--out", str(out)],
        cwd=tmp_path, env={**os.environ, **env}, check=True, capture_output=True, timeout=600,
    )  # fmt: skip
    return out


def _stored_runs(tmp_path, command: list[str], programs: int) -> tuple[Path, list[Path]]:
    """The output of ``command`` traced without a store, then exporting into an empty store
    (``programs`` entries), then loading from it, and last from another empty store that the
    shipped programs fill (``tools/ship_programs.py`` ships this command's)."""
    cache = str(tmp_path / "cache")
    traced = _fresh(tmp_path, "traced", "0", command)
    runs = [_fresh(tmp_path, "exported", cache, command)]
    entries = (tmp_path / "cache" / "programs").glob("*.jaxprogram")
    assert [read_header(p)["kind"] for p in entries].count("program") == programs
    runs.append(_fresh(tmp_path, "loaded", cache, command))
    runs.append(_fresh(tmp_path, "shipped", str(tmp_path / "fresh"), command, shipped=True))
    copied = {p.name for p in (tmp_path / "fresh" / "programs").glob("*.jaxprogram")
              if read_header(p)["kind"] == "program"}  # fmt: skip
    assert copied <= {p.name for p in SHIPPED.glob("*.jaxprogram")}, "a program was traced"
    return traced, runs


@pytest.mark.slow
def test_the_main_job_loads_its_programs_and_answers_as_the_traced_ones(tmp_path):
    """``simulate --bpm 60`` (the batch solve and the quasi-static strokes) from fresh
    processes. Summaries and traces agree to round-off: the same StableHLO, compiled alike;
    1e-12 relative is many times float64's rounding of a beat, far below any solver
    tolerance."""
    traced, runs = _stored_runs(tmp_path, ["cardiosoft.simulate", "--bpm", "60"], programs=2)
    want = json.loads((traced / "summary.json").read_text())
    want_traces = np.genfromtxt(traced / "traces.csv", delimiter=",", names=True)
    for out in runs:
        summary = json.loads((out / "summary.json").read_text())
        for expected, got in zip(want["records"], summary["records"], strict=True):
            for key, value in expected.items():
                if isinstance(value, float):
                    assert got[key] == pytest.approx(value, rel=1e-12, abs=1e-12), key
        # traces.csv holds 8 significant digits: round-off may move the last one
        traces = np.genfromtxt(out / "traces.csv", delimiter=",", names=True)
        assert traces.dtype.names == want_traces.dtype.names
        for name in traces.dtype.names:
            column = want_traces[name]
            atol = 1e-7 * np.nanmax(np.abs(column), initial=0.0)
            np.testing.assert_allclose(traces[name], column, rtol=1e-7, atol=atol, err_msg=name)


@pytest.mark.slow
def test_a_design_loads_its_programs_and_answers_as_the_traced_one(tmp_path):
    """The README's design question: the search's two programs (the orbits and their
    implicit derivatives) and the verifying run's come from the store, and so does the coarse
    grid's evaluation (a value entry). The same programs give the same search: the design and
    its SVs agree to 1e-9 relative (round-off carried through a few dozen least-squares
    steps)."""
    question = ["--target-sv", "70", "--afterload", "90", "--bpm", "60"]
    traced, runs = _stored_runs(tmp_path, ["cardiosoft.design", *question], programs=4)
    kinds = [read_header(p)["kind"] for p in (tmp_path / "cache" / "programs").iterdir()]
    assert kinds.count("value") == 1, kinds  # the grid, read back by the "loaded" run
    want = json.loads((traced / "design.json").read_text())
    for out in runs:
        got = json.loads((out / "design.json").read_text())
        for key in ("omega", "shortening"):
            assert got[key] == pytest.approx(want[key], rel=1e-9), key
        for expected, target in zip(want["targets"], got["targets"], strict=True):
            assert target["sv_ml"] == pytest.approx(expected["sv_ml"], rel=1e-9)
