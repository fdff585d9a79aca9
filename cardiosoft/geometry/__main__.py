"""``python -m cardiosoft.geometry``: the Fig. 7(a) table (and figure)."""

from __future__ import annotations

import argparse
import sys


def main(argv=None) -> int:
    import jax
    import numpy as np

    from cardiosoft._cli import fail
    from cardiosoft.files import refuse_overwrite
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


if __name__ == "__main__":
    raise SystemExit(main())
