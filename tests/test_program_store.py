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
import jax.numpy as jnp
import numpy as np
import pytest

from cardiosoft.program_store import stored_call, use_program_store

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


def test_without_a_store_the_function_is_traced_as_usual():
    use_program_store(None)
    TRACED.clear()
    out = stored_call(_beat_like, NUMBERS, 5.0)
    np.testing.assert_array_equal(out["y"], [1.0, 6.0, 11.0])
    assert TRACED == [5.0]


@pytest.mark.slow
def test_the_main_job_loads_its_program_and_answers_as_the_traced_one(tmp_path):
    """``simulate --bpm 60`` from fresh processes: traced without a store, then exporting into
    an empty store, then loading from it. Their summaries and traces agree to round-off (the
    same StableHLO, compiled alike: 1e-12 relative is many times float64's rounding of a
    beat, far below any solver tolerance)."""

    def run(name, cache):
        env = {**os.environ, "CARDIOSOFT_COMPILE_CACHE": cache}
        out = tmp_path / name
        subprocess.run(
            [sys.executable, "-m", "cardiosoft.simulate", "--bpm", "60", "--quiet", "--no-plot",
             "--out", str(out)],
            cwd=tmp_path, env=env, check=True, capture_output=True, timeout=600,
        )  # fmt: skip
        summary = json.loads((out / "summary.json").read_text())
        traces = np.genfromtxt(out / "traces.csv", delimiter=",", names=True)
        return summary, traces

    cache = str(tmp_path / "cache")
    traced, traced_traces = run("traced", "0")
    runs = [run("exported", cache)]
    assert len(list((tmp_path / "cache" / "programs").glob("*.jaxprogram"))) == 1
    runs.append(run("loaded", cache))
    for summary, traces in runs:
        for want, got in zip(traced["records"], summary["records"], strict=True):
            for key, value in want.items():
                if isinstance(value, float):
                    assert got[key] == pytest.approx(value, rel=1e-12, abs=1e-12), key
        # traces.csv holds 8 significant digits: round-off may move the last one
        assert traces.dtype.names == traced_traces.dtype.names
        for name in traces.dtype.names:
            want = traced_traces[name]
            atol = 1e-7 * np.nanmax(np.abs(want), initial=0.0)
            np.testing.assert_allclose(traces[name], want, rtol=1e-7, atol=atol, err_msg=name)
