"""The command line of the geometrical model: ``cardiosoft geometry`` /
``python -m cardiosoft.geometry``, the Fig. 7(a) table (and figure)."""

from __future__ import annotations

__all__ = ["main", "parser"]


def parser(prog: str | None = None):
    """The argument parser of ``cardiosoft geometry``."""
    from cardiosoft._cli import command_parser

    p = command_parser(
        "geometry",
        "Apex translation and rotation of the paper's geometrical model (Fig. 7(a)).",
        prog=prog,
    )
    p.add_argument("--plot", metavar="FILE", help="also draw Fig. 7(a) to FILE (png/pdf/svg)")
    p.add_argument("--force", action="store_true", help="overwrite an existing --plot FILE")
    return p


def _print_tables(shell, omegas, shortenings, dz, dalpha) -> None:
    from cardiosoft.geometry import cavity_volume
    from cardiosoft.units import mm

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


def main(argv=None, prog: str | None = None) -> int:
    """``cardiosoft geometry``: returns the exit status (0, or 2 for bad input)."""
    import sys

    import jax
    import numpy as np

    from cardiosoft.console import fail
    from cardiosoft.files import refuse_overwrite
    from cardiosoft.geometry import Shell, apex_motion_table

    args = parser(prog).parse_args(argv)
    jax.config.update("jax_enable_x64", True)
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
    _print_tables(shell, omegas, shortenings, dz, dalpha)
    if args.plot:
        from cardiosoft.plots import plot_apex_motion

        plot_apex_motion(omegas, shortenings, dz, dalpha, args.plot)
        print(f"\nwrote {args.plot}", file=sys.stderr)
    return 0
