"""Writing files whole, and reading their hashes: plain Python, nothing else of cardiosoft.

Files are written whole or not at all: each goes to a temporary file in the destination folder
and is renamed into place only when complete. An existing output is not overwritten unless asked.
"""

from __future__ import annotations

import contextlib
import hashlib
import math
import os
import shutil
import tempfile
from pathlib import Path

__all__ = [
    "atomic_path",
    "check_writable_folder",
    "json_ready",
    "refuse_overwrite",
    "sha256",
    "write_together",
]


def json_ready(value):
    """``value`` with every non-finite float in it (inside dicts, lists and tuples, which
    become lists) as None: JSON has no NaN, and a number that could not be computed (an
    efficiency of a zero stroke, a failed member's trace) is null."""
    if isinstance(value, dict):
        return {k: json_ready(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [json_ready(v) for v in value]
    return None if isinstance(value, float) and not math.isfinite(value) else value


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


@contextlib.contextmanager
def write_together(folder):
    """Yield a staging folder inside ``folder``: the files written there are moved into
    ``folder`` (each by an atomic rename, in the order they were written) when the block ends,
    none if it raises; the staging folder is removed either way. For a command's outputs, so
    that a failure halfway leaves no half of them behind."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(dir=folder, prefix=".staging-"))
    try:
        yield staging
        written = sorted(staging.iterdir(), key=lambda p: (p.stat().st_mtime_ns, p.name))
        for path in written:
            path.replace(folder / path.name)
    finally:
        shutil.rmtree(staging, ignore_errors=True)


def sha256(path) -> str:
    """Hex SHA-256 of the file's bytes (what a model card records)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 16), b""):
            h.update(block)
    return h.hexdigest()


def check_writable_folder(path, what: str = "--out") -> None:
    """Raise ``ValueError`` unless ``path`` is, or could be made as, a folder this process can
    write into; nothing is created. For checking an output folder before a long computation."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise ValueError(f"{what} {path}: exists and is not a folder")
    parent = path
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise ValueError(f"{what} {path}: {parent} is a file, not a folder")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise ValueError(f"{what} {path}: no permission to write in {parent}")
