"""Write the shell's inflation curve (python -m fit.membrane), or print the study.

    python -m fit.membrane                   # fit/data/membrane_inflation.csv (--force: overwrite)
    python -m fit.membrane --out PATH --elements N --p-max MMHG --step MMHG
    python -m fit.membrane --study           # the numbers of fit/membrane's docstring

The file is written whole or not at all; the table and its sha256 are printed. Bad input: one
line on stderr, exit status 2, nothing written.
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import jax
import numpy as np

from cardiosoft.files import atomic_path, refuse_overwrite, sha256
from cardiosoft.geometry import Shell
from cardiosoft.geometry import cable_length as helix_length
from cardiosoft.units import ml, mm, mmHg
from fit.membrane import (
    N_ELEMENTS,
    P_MAX_MMHG,
    STEP_MMHG,
    Inflation,
    _check_pressures,
    cable_length,
    embed_helix,
    inflation,
    measures,
    rest_state,
    shell_membrane,
    solve,
)

STUDY_MMHG = (30.0, 60.0, 90.0, 150.0, 250.0)


def study(n_elements: int = N_ELEMENTS) -> dict:
    """The numbers of the module docstring (SI): convergence N vs 2N, the slope at rest, the
    softest point of the curve, the cables' lengthening and the restraint, the junction."""
    p = np.asarray(STUDY_MMHG) * mmHg
    shell = Shell()
    out = {"n": n_elements, "pressure": p}
    for n in (n_elements, 2 * n_elements):
        out[n] = inflation(p, n)
        m = shell_membrane(n)
        rest = measures(m, rest_state(m))
        out[n, "rest_compliance"] = float(rest.mid_compliance)  # see fit.membrane's docstring
    curve = inflation(np.r_[0.0, 0.5, np.arange(2.5, P_MAX_MMHG + 0.1, 2.5)] * mmHg, n_elements)
    out["curve"] = curve
    # the cables: material helices on the outer surface at 150 mmHg, free inflation
    m = shell_membrane(n_elements)
    (state,) = solve(m, [150 * mmHg])
    out["cables"] = {}
    for omega in range(1, 7):
        e = embed_helix(shell, n_elements, omega)
        rest, swollen = (float(cable_length(m, e, x)) for x in (m.nodes, state.x))
        out["cables"][omega] = (float(helix_length(shell, omega)), swollen - rest)
    out["restrained"] = inflation(p[[0, 2, 3]], n_elements, restrain_omega=4.0)
    out["free"] = out[n_elements]._replace(
        **{k: v[[0, 2, 3]] for k, v in out[n_elements]._asdict().items()}
    )
    out["junction"] = {
        h: float(inflation([150 * mmHg], n_elements, Shell(apex_height=h)).swelling[0])
        for h in (
            float(shell.apex_height) - 0.44 * mm,
            float(shell.apex_height),
            float(shell.apex_height) + 0.44 * mm,
        )
    }
    return out


def format_study(s: dict) -> str:
    """The study as text (user units)."""
    n, p = s["n"], s["pressure"] / mmHg
    a, b = s[n], s[2 * n]
    lines = [f"Swelling at zero pull (ml), N = {n} and {2 * n} elements:"]
    for i, pi in enumerate(p):
        lines.append(
            f"  {pi:5.0f} mmHg  {a.swelling[i] / ml:8.4f}  {b.swelling[i] / ml:8.4f}  "
            f"(rel. diff {abs(a.swelling[i] / b.swelling[i] - 1):.1e}; "
            f"volume {a.volume[i] / ml:.3f}"
            f" vs {b.volume[i] / ml:.3f} ml; mid-surface swelling {a.mid_swelling[i] / ml:.4f} ml;"
            f" plug {a.plug_displacement[i] / mm:+.3f} mm; max stretch {a.max_stretch[i]:.4f};"
            f" min tension {a.min_tension[i]:.1f} N/m)"
        )
    c = [s[k, "rest_compliance"] / (ml / mmHg) for k in (n, 2 * n)]
    lines.append(
        f"Slope at zero pressure (mid-surface, linear): {1 / c[0]:.3f} / {1 / c[1]:.3f} "
        f"mmHg/ml (N / 2N)"
    )
    curve = s["curve"]
    k_stiff = 1 / (curve.compliance / (ml / mmHg))
    i_max, i_min = int(np.argmax(k_stiff)), int(np.argmin(k_stiff))
    lines.append(
        f"Tangent stiffness dP/dV: {k_stiff[0]:.3f} mmHg/ml at 0, {k_stiff[1]:.3f} at "
        f"{curve.pressure[1] / mmHg:g} mmHg, highest {k_stiff[i_max]:.3f} at "
        f"{curve.pressure[i_max] / mmHg:.1f} mmHg, lowest {k_stiff[i_min]:.3f} at "
        f"{curve.pressure[i_min] / mmHg:.1f} mmHg ({curve.swelling[i_min] / ml:.1f} ml), "
        f"{k_stiff[-1]:.3f} at {curve.pressure[-1] / mmHg:.0f} mmHg"
    )
    lines.append("Cables at 150 mmHg (material helices on the outer surface, free inflation):")
    for omega, (length, dl) in s["cables"].items():
        lines.append(
            f"  Omega {omega}: L {length / mm:6.1f} mm, lengthens by {dl / mm:5.2f} mm "
            f"= {100 * dl / length:4.1f} % of L = {dl / (0.4 * length):.2f} of the stroke "
            f"0.4 L"
        )
    free, held = s["free"], s["restrained"]
    lines.append("Six Omega-4 cables held at their rest length (smeared; an upper bound):")
    for i, pi in enumerate(held.pressure / mmHg):
        lines.append(
            f"  {pi:5.0f} mmHg  swelling {held.swelling[i] / ml:7.3f} ml (free "
            f"{free.swelling[i] / ml:7.3f}), tension {held.cable_tension[i]:.2f} N per "
            f"cable, min membrane tension {held.min_tension[i]:.1f} N/m"
        )
    lines.append(
        "Junction height (mm) -> swelling at 150 mmHg (ml): "
        + ", ".join(f"{h / mm:.2f}: {v / ml:.4f}" for h, v in s["junction"].items())
    )
    return "\n".join(lines)


# ------------------------------------------------------------------------------ the data file

DATA_FILE = Path(__file__).resolve().parent.parent / "data" / "membrane_inflation.csv"
COLUMNS = (
    "pressure_mmHg",
    "volume_ml",
    "swelling_ml",
    "compliance_ml_per_mmHg",
    "plug_displacement_mm",
    "max_stretch",
    "provenance",
)


def write_csv(path, result: Inflation, provenance: str) -> None:
    """Write ``result`` as a ``membrane_inflation`` file (fit/data/README.md), atomically."""
    rows = zip(
        result.pressure / mmHg,
        result.volume / ml,
        result.swelling / ml,
        result.compliance / (ml / mmHg),
        result.plug_displacement / mm,
        result.max_stretch,
        strict=True,
    )
    with atomic_path(path) as tmp, open(tmp, "w", newline="", encoding="utf-8") as f:
        f.write(
            "# Computed, not transcribed: the paper's shell (Sec. II-B) inflated at zero cable "
            "pull as an incompressible Yeoh membrane (material Sec. II-D); volume = the paper's "
            "108.6 ml + swelling of the inner surface. Regenerate: python -m fit.membrane.\n"
        )
        w = csv.writer(f, lineterminator="\n")
        w.writerow(COLUMNS)
        for p, v, s, c, dz, lam in rows:
            w.writerow(
                [
                    f"{p:g}",
                    f"{v:.4f}",
                    f"{s:.4f}",
                    f"{c:.6f}",
                    f"{dz:.4f}",
                    f"{lam:.5f}",
                    provenance,
                ]
            )


def main(argv=None) -> int:
    jax.config.update("jax_enable_x64", True)
    parser = argparse.ArgumentParser(
        prog="python -m fit.membrane", description=__doc__.split("\n")[0]
    )
    parser.add_argument(
        "--out",
        metavar="PATH",
        default=str(DATA_FILE),
        help="where to write the curve (default: fit/data/membrane_inflation.csv)",
    )
    parser.add_argument("--force", action="store_true", help="overwrite an existing file")
    parser.add_argument(
        "--elements",
        type=int,
        default=N_ELEMENTS,
        metavar="N",
        help=f"linear elements on the meridian (default {N_ELEMENTS})",
    )
    parser.add_argument(
        "--p-max",
        type=float,
        default=P_MAX_MMHG,
        metavar="MMHG",
        help=f"top pressure, mmHg (default {P_MAX_MMHG:g})",
    )
    parser.add_argument(
        "--step",
        type=float,
        default=STEP_MMHG,
        metavar="MMHG",
        help=f"pressure step of the table, mmHg (default {STEP_MMHG:g})",
    )
    parser.add_argument(
        "--study",
        action="store_true",
        help="print the checks and the cable measurement; write nothing",
    )
    args = parser.parse_args(argv)
    try:
        if args.elements < 4:
            raise ValueError(f"--elements = {args.elements} is outside the allowed range [4, inf)")
        _check_pressures(args.p_max * mmHg)
        if not 0 < args.step <= args.p_max:
            raise ValueError(
                f"--step = {args.step:g} mmHg is outside the allowed range "
                f"(0, {args.p_max:g}] mmHg (--p-max)"
            )
        if not args.study:
            refuse_overwrite(args.out, args.force)
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    if args.study:
        print(format_study(study(args.elements)))
        return 0
    pressures = np.arange(0.0, args.p_max + 0.5 * args.step, args.step) * mmHg
    result = inflation(pressures, args.elements)
    options = "" if args.elements == N_ELEMENTS else f" --elements {args.elements}"
    options += "" if args.p_max == P_MAX_MMHG else f" --p-max {args.p_max:g}"
    options += "" if args.step == STEP_MMHG else f" --step {args.step:g}"
    provenance = (
        f"computed: python -m fit.membrane{options} (axisymmetric incompressible Yeoh "
        f"membrane, {args.elements} linear elements; shell Sec. II-B, material Sec. II-D)"
    )
    write_csv(args.out, result, provenance)
    print(Path(args.out).read_text(encoding="utf-8"), end="")
    print(f"sha256 {sha256(args.out)}  {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
