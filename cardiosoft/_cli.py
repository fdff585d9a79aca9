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


def geometry_main(argv=None) -> int:
    """``python -m cardiosoft.geometry``: the Fig. 7(a) table (and figure)."""
    import argparse

    import jax
    import numpy as np

    from cardiosoft.geometry import Shell, apex_motion_table, cavity_volume
    from cardiosoft.units import mm

    jax.config.update("jax_enable_x64", True)
    parser = argparse.ArgumentParser(
        prog="python -m cardiosoft.geometry",
        description="Apex translation and rotation of the paper's geometrical model (Fig. 7(a)).",
    )
    parser.add_argument("--plot", metavar="FILE", help="also draw Fig. 7(a) to FILE (png/pdf/svg)")
    parser.add_argument("--force", action="store_true", help="overwrite an existing --plot FILE")
    args = parser.parse_args(argv)
    try:
        if args.plot:
            from cardiosoft.plots import check_figure_path

            check_figure_path(args.plot)
            refuse_overwrite(args.plot, args.force)
        shell = Shell()
        omegas = np.arange(1, 7)
        shortenings = np.round(np.arange(1, 7) * 0.1, 2)
        dz, dalpha = apex_motion_table(shell, omegas, shortenings)
    except ValueError as err:
        return fail(err)

    print(
        f"Shell A = {float(shell.A) / mm:g} mm, B = {float(shell.B) / mm:g} mm, "
        f"w = {float(shell.w) / mm:g} mm, apex plane {float(shell.apex_height) / mm:g} mm; "
        f"cavity {float(cavity_volume(shell)) / 1e-6:.1f} ml"
    )
    for title, values, fmt in (
        ("Apex translation |dz| [mm] (towards the base)", dz, "{:7.1f}"),
        ("Apex rotation |dalpha| [deg]", dalpha, "{:7.1f}"),
    ):
        print(f"\n{title}")
        print("  C \\ Omega" + "".join(f"{o:7d}" for o in omegas))
        for c, row in zip(shortenings, values, strict=True):
            print(f"  {c:9.1f}" + "".join(fmt.format(v) for v in row))
    if args.plot:
        from cardiosoft.plots import plot_apex_motion

        plot_apex_motion(omegas, shortenings, dz, dalpha, args.plot)
        print(f"\nwrote {args.plot}", file=sys.stderr)
    return 0
