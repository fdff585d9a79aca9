"""Shared plumbing of the command-line entry points: error reporting and safe file output.

Numerics never live here. Files are written whole or not at all: each goes to a temporary file in
the destination folder and is renamed into place only when complete.
"""

from __future__ import annotations

import contextlib
import os
import sys
import tempfile
from pathlib import Path

EXIT_BAD_INPUT = 2


def fail(err: BaseException) -> int:
    """Print one line for a bad input and return the CLI's bad-input exit code."""
    print(f"error: {err}", file=sys.stderr)
    return EXIT_BAD_INPUT


def refuse_overwrite(path, force: bool) -> None:
    """Raise ``ValueError`` if ``path`` exists and ``force`` was not given."""
    if Path(path).exists() and not force:
        raise ValueError(f"output {path} exists already; pass --force to overwrite it")


@contextlib.contextmanager
def atomic_path(path):
    """Yield a temporary path next to ``path``; rename it onto ``path`` only on success."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=path.suffix)
    os.close(fd)
    try:
        yield Path(tmp)
        os.replace(tmp, path)
    finally:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
