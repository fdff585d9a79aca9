"""Shared plumbing of the command-line entry points: error reporting, the compile cache.

Numerics never live here; safe file output is :mod:`cardiosoft.files`.
"""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

EXIT_BAD_INPUT = 2
CACHE_VARIABLE = "CARDIOSOFT_COMPILE_CACHE"
"""``0`` switches the compile cache off; a folder puts it there (:func:`use_compile_cache`)."""


def fail(err: BaseException) -> int:
    """Print one line for a bad input and return the CLI's bad-input exit code."""
    print(f"error: {err}", file=sys.stderr)
    return EXIT_BAD_INPUT


def compile_cache_folder() -> Path | None:
    """Where the compile cache lives: ``$CARDIOSOFT_COMPILE_CACHE`` if it names a folder, None
    if it is ``0``, else ``$XDG_CACHE_HOME/cardiosoft/jax`` (``~/.cache/cardiosoft/jax``)."""
    setting = os.environ.get(CACHE_VARIABLE, "").strip()
    if setting == "0":
        return None
    if setting and setting != "1":
        return Path(setting).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "cardiosoft" / "jax"


def use_compile_cache() -> Path | None:
    """Keep the CLI's compiled programs on disk, so that the next process loads them instead of
    compiling them again (JAX's persistent compilation cache). Returns the folder, or None.

    Nearly all of a fresh CLI process's time is tracing and compiling the same few programs
    (benchmarks/startup.py, benchmarks/design.py); tracing is redone, XLA compilation is not.
    Call it in a ``__main__`` block only, before anything is compiled: library imports and the
    ``main()`` functions (which tests call in-process) leave JAX's global settings alone.

    - On by default; ``CARDIOSOFT_COMPILE_CACHE=0`` switches it off, ``=/some/folder`` moves it.
      A cache folder of the user's own (``JAX_COMPILATION_CACHE_DIR``) is kept as it is.
    - A folder that cannot be created or written: one warning line, and the run goes on
      without a cache.
    - JAX refuses to store a program with host callbacks, and equinox's runtime checks
      (``eqx.error_if``, inside diffrax) are host callbacks that raise: the batch solve would
      never be stored. The process therefore resolves those checks to NaN instead
      (``EQX_ON_ERROR=nan``), unless the user chose a mode. cardiosoft never relies on them
      being raised: its solves run with ``throw=False`` and report diffrax's result codes; the
      checks left are diffrax's on the save times (which cardiosoft builds increasing, clipped
      to the beat: a violation would give non-finite samples, which ``periodic_beats`` reports
      as a failed solve) and lineax's on the derivatives of a stiff solver's linear solves,
      which the implicit derivative of an orbit never feeds a NaN
      (:func:`cardiosoft.solve.orbit_beat`). The whole analysis is in the commit that added
      this function.
    """
    import jax

    if os.environ.get("JAX_COMPILATION_CACHE_DIR"):  # JAX itself reads it: the user's own
        folder = Path(os.environ["JAX_COMPILATION_CACHE_DIR"])
    else:
        folder = compile_cache_folder()
        if folder is None:
            return None
        try:
            folder.mkdir(parents=True, exist_ok=True)
            with tempfile.TemporaryFile(dir=folder):  # writable? (os.access ignores root, ACLs)
                pass
        except OSError as err:
            print(
                f"warning: compile cache {folder}: {err.strerror or err}; running without it "
                f"(set {CACHE_VARIABLE}=0 to silence this)",
                file=sys.stderr,
            )
            return None
        jax.config.update("jax_compilation_cache_dir", str(folder))
    if "EQX_ON_ERROR" not in os.environ:
        import equinox._errors

        # equinox reads EQX_ON_ERROR once, when imported (``import cardiosoft`` did that), and
        # looks this module global up each time it traces a check: set before any tracing.
        if getattr(equinox._errors, "EQX_ON_ERROR", None) == "raise":
            equinox._errors.EQX_ON_ERROR = "nan"
    return folder
