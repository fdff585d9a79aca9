"""``cardiosoft export --svzerod SCENE --out FILE``: a scene written as an svZeroDSolver model
(the writers: :mod:`cardiosoft.network.export` for a closed loop,
:mod:`cardiosoft.network.export_open_loop` for the pump with a Windkessel or on the bench)."""

from __future__ import annotations

import json
import sys
from pathlib import Path


def parser(prog: str | None = None):
    """The argument parser of ``cardiosoft export``."""
    from cardiosoft._cli import command_parser
    from cardiosoft.network.pump_in_model import DEFAULT_UNITS, UNIT_SYSTEMS

    p = command_parser(
        "export",
        "Write a scene as an svZeroDSolver model (JSON): a closed loop, the pump with a "
        "Windkessel (lv-systemic, rv-pulmonary) or on the dynamic bench (bench-dynamic).",
        prog=prog,
    )
    p.add_argument(
        "--svzerod", metavar="SCENE", required=True, help="a shipped scene's name or a scene file"
    )
    p.add_argument(
        "--afterload",
        metavar="MMHG",
        type=float,
        help="the bench's column head at the pump base (mmHg; default the scene's first)",
    )
    p.add_argument("--out", metavar="FILE", required=True, help="the JSON file to write")
    p.add_argument(
        "--units",
        choices=tuple(UNIT_SYSTEMS),
        default=DEFAULT_UNITS,
        help=f"the file's units (default {DEFAULT_UNITS}; mmHg: mmHg, ml, s; si: Pa, m^3, s)",
    )
    p.add_argument("--beats", type=int, default=10, help="beats the model runs (default 10)")
    p.add_argument("--force", action="store_true", help="overwrite an existing FILE")
    return p


def main(argv=None, prog: str | None = None) -> int:
    """``cardiosoft export``: returns the exit status (0, or 2 for bad input)."""
    import jax

    from cardiosoft.console import fail
    from cardiosoft.files import atomic_path, refuse_overwrite
    from cardiosoft.scene import load_scene
    from cardiosoft.scene_tools import check_supported, tools
    from cardiosoft.units import mmHg

    args = parser(prog).parse_args(argv)
    jax.config.update("jax_enable_x64", True)
    try:
        if not 1 <= args.beats <= 500:
            raise ValueError(f"--beats = {args.beats}: allowed 1 to 500")
        scene = load_scene(args.svzerod)
        check_supported(scene, "export", f"--svzerod {args.svzerod}")
        given = None if args.afterload is None else (args.afterload,)
        heads = tools(scene).column_heads(scene, given, "set")  # None without a column
        if heads is not None:  # the file holds one head
            if given is None and len(heads) > 1:
                print(
                    f"{scene.name} has the column heads {', '.join(f'{h:g}' for h in heads)} "
                    "mmHg: writing the first (--afterload MMHG writes another)",
                    file=sys.stderr,
                )
            scene = scene.replace(afterloads=(heads[0] * mmHg,))
        refuse_overwrite(Path(args.out), args.force)
        model = tools(scene).svzerod_model(scene, args.units, args.beats)
    except (ValueError, OSError) as err:
        return fail(err)
    with atomic_path(args.out) as tmp:
        Path(tmp).write_text(json.dumps(model, indent=2) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
