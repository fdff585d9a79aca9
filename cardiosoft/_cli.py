"""Shared plumbing of the command-line entry points: error reporting.

Numerics never live here; safe file output is :mod:`cardiosoft.files`.
"""

from __future__ import annotations

import sys

EXIT_BAD_INPUT = 2


def fail(err: BaseException) -> int:
    """Print one line for a bad input and return the CLI's bad-input exit code."""
    print(f"error: {err}", file=sys.stderr)
    return EXIT_BAD_INPUT
