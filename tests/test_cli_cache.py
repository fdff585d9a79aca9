"""The command lines' compile cache (cardiosoft._cli.use_compile_cache): on by default in a
folder of its own, with the exported programs in its ``programs/`` (off alone with
``CARDIOSOFT_PROGRAM_STORE=0``), off with ``CARDIOSOFT_COMPILE_CACHE=0``, harmless when the
folder cannot be written, and reused by the next process (JAX's log says so; no clock is read).

Each test sets ``CARDIOSOFT_COMPILE_CACHE`` or ``XDG_CACHE_HOME`` to a folder under tmp_path,
so that nothing is written to the user's own cache.
"""

import json
import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent


def python(*args, **env):
    """A fresh ``python`` process in the repository, with ``env`` added (None: unset)."""
    env = {k: v for k, v in {**os.environ, **env}.items() if v is not None}
    done = subprocess.run(
        [sys.executable, *args], cwd=REPO, env=env, capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr
    return done


def simulate(tmp_path, name, *args, **env):
    """``python -m cardiosoft.simulate`` writing to tmp_path/name, with ``env`` added."""
    out = tmp_path / name
    done = python("-m", "cardiosoft.simulate", *args, "--no-plot", "--out", str(out), **env)
    return done, json.loads((out / "summary.json").read_text())


def test_default_folder_follows_xdg_cache_home_and_a_second_process_reuses_it(tmp_path):
    """The default folder, then a warm second process: the batch solve is stored (equinox's
    raising checks would keep it out: EQX_ON_ERROR=nan in the CLI) and loaded, not compiled.
    Loaded, it is not traced, and the process imports neither diffrax nor the solvers under
    it (issue #41: 0.4-0.5 s of the warm main job; Python's import log says so)."""
    xdg = tmp_path / "xdg"
    env = dict(
        XDG_CACHE_HOME=str(xdg),
        CARDIOSOFT_COMPILE_CACHE=None,
        EQX_ON_ERROR=None,
        JAX_COMPILATION_CACHE_DIR=None,
        JAX_LOG_COMPILES="1",
    )
    cold, first = simulate(tmp_path, "cold", "--bpm", "30", **env)
    folder = xdg / "cardiosoft" / "jax"
    stored = {p.name.split("-")[0] for p in folder.iterdir()}
    assert {"jit__solve", "jit_static_strokes"} <= stored, stored
    # and beside the executables, the two programs exported (cardiosoft.program_store)
    assert len(list((folder / "programs").glob("*.jaxprogram"))) == 2
    assert "Persistent compilation cache hit for 'jit__solve'" not in cold.stderr
    # a fresh machine's first run: the two were shipped with the package, copied, not traced
    # (program_store.SHIPPED; an export's trace is logged as <function>_exported)
    assert "_exported for jit" not in cold.stderr, "the main job's shipped programs are stale"
    warm, second = simulate(tmp_path, "warm", "--bpm", "30", PYTHONPROFILEIMPORTTIME="1", **env)
    for name in ("jit__solve", "jit_static_strokes"):
        assert f"Persistent compilation cache hit for '{name}'" in warm.stderr
    assert second == first  # the same numbers from the loaded program
    imported = {line.rsplit("|", 1)[1].strip() for line in warm.stderr.splitlines()
                if line.startswith("import time:")}  # fmt: skip
    assert "jax" in imported  # the log is there
    assert not imported & {"diffrax", "optimistix", "lineax"}, "a warm run imported a solver"


def test_cache_off_writes_no_folder(tmp_path):
    xdg = tmp_path / "xdg"
    done, _ = simulate(
        tmp_path,
        "off",
        "--scene",
        "bench-static",
        XDG_CACHE_HOME=str(xdg),
        CARDIOSOFT_COMPILE_CACHE="0",
    )
    assert not xdg.exists()
    assert "warning" not in done.stderr


def test_program_store_off_keeps_the_compile_cache(tmp_path):
    folder = tmp_path / "cache"
    simulate(
        tmp_path,
        "no-store",
        "--scene",
        "bench-static",
        CARDIOSOFT_COMPILE_CACHE=str(folder),
        CARDIOSOFT_PROGRAM_STORE="0",
    )
    assert any(p.name.startswith("jit_static_strokes") for p in folder.iterdir())
    assert not (folder / "programs").exists()


def test_a_folder_that_cannot_be_written_warns_once_and_runs_without_cache(tmp_path):
    blocker = tmp_path / "a-file"  # a file where a folder should be: even root cannot create it
    blocker.write_text("")
    done, record = simulate(
        tmp_path,
        "unwritable",
        "--scene",
        "bench-static",
        CARDIOSOFT_COMPILE_CACHE=str(blocker / "jax"),
    )
    warnings = [line for line in done.stderr.splitlines() if line.startswith("warning")]
    assert len(warnings) == 1 and "compile cache" in warnings[0], done.stderr
    assert record  # the run itself went on


def test_library_import_leaves_jax_and_equinox_settings_alone():
    code = (
        "import cardiosoft, cardiosoft.simulate, cardiosoft.design, equinox._errors as e, jax;"
        "from jax._src import config as c;"
        "print(c.compilation_cache_dir.value, e.EQX_ON_ERROR)"
    )
    out = python("-c", code, EQX_ON_ERROR=None, JAX_COMPILATION_CACHE_DIR=None)
    assert out.stdout.split() == ["None", "raise"]

