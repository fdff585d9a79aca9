"""The 30-bpm bench's ring, diagnosed on both shipped pumps, and its candidate causes tested
(issue #39, items 2 and 3).

    python -m fit.ring                 # the tables (about 1-2 min on 2 cores)
    python -m fit.ring --out DIR       # and the figure, DIR/ring.png

**The diagnosis**, per pump (ss950-v3, the default; ss950-v4, the membrane-true chamber, each
with its own calibrated bench: the scenes' ``[calibration]`` tables) and afterload, from the
30-bpm periodic beat:

- where in the stroke the peak force falls: the pull x at the peak over the stroke;
- the ring: the bench linearised at the instant of the peak, the chamber's compliance
  ``C_ch = 1 / (d2U/dV2)`` and the column's ``C_col = A_col / (rho g)`` in series through the
  line's inertance ``L = rho l / A_t + rho h / A_col`` with the resistance ``R = R_Poiseuille +
  2 K |q|`` (the minor loss at the flow of that instant):
  ``f = 1 / (2 pi sqrt(L C))``, ``C = C_ch C_col / (C_ch + C_col)``, ``zeta = R sqrt(C / L) / 2``.
  The chamber's compliance is the static one: the shell's viscoelastic branch stiffens it at
  the ring's frequency, so f is a lower bound;
- the chamber's compliance dV/dP at that instant (ml/mmHg);
- the force-displacement curve beside the paper's Fig. 10(d) description (section III-D): the
  force "increases almost linearly with the applied displacement, until reaching its peak,
  and then decreases as the inner folds appear". Reported: whether the curve falls after its
  peak (by more than 5 % before the stroke ends) and the quasi-static peak's position.

**The folded shell's softness** (candidate b). With E_u pinned by the membrane (ss950-v4),
the static SVs ask for kappa = 1.28 (its fit; ss950-v3 holds 0.81). Reported per run: how far
into the stroke the chamber stays taut (its volume above the unloaded V_u, where the membrane
is stretched and its softening acts), and whether the peak falls while it is taut.

**The compliant tube and the silicone's loss** (candidates c and d), as orders of magnitude at
each pump's 60-mmHg ring, from stated physics and never from the forces:

- the tube's wall compliance ``2 pi r^3 l / (E_t h)`` against the chamber's, its wave
  transit time ``l / c`` (Moens-Korteweg, ``c = sqrt(E_t h / (2 rho r))``) against the ring's
  period, and the damping that unsteady friction adds: at Womersley number
  ``alpha = r sqrt(omega rho / mu)`` the oscillatory resistance is ``alpha / (4 sqrt 2)``
  Poiseuille's (Womersley 1955, large alpha). ``E_t`` from Gent's relation for a Shore 50-70A
  silicone tube (2.2-5.4 MPa, :data:`TUBE_MODULUS_PA`), walls of 1.5-3 mm;
- the silicone's loss factor, ``zeta = tan(delta) / 2`` times the chamber's share of the
  ring's strain energy, ``C_col / (C_ch + C_col)`` (the same volume swings through both, so
  the stiffer chamber holds most of it): tan(delta) 0.05-0.15 is the range of platinum-cure
  silicone elastomers at 1-10 Hz (Smooth-On publishes none for Smooth-Sil 950), beside the
  calibrated viscoelastic branch's own loss factor at the ring's frequency and the damping it
  gives (which the simulated bench has and the linearised ring's zeta leaves out).

The silicone's loss is also simulated in place of the calibrated branch: a standard linear
solid whose loss factor peaks at 0.05 and at 0.15 at the 60-mmHg ring (:func:`silicone_branch`),
alone and with the crosshead's ramp. The tube's wall is not simulated: the model has no node
between the chamber and the line, and its largest share (a compliance beside the chamber's,
2-10 %) would lower the ring's surge impedance ``sqrt(L / C)``, the force of a start at full
speed, by at most 1-5 %.

**The crosshead.** The model starts and stops the disk at full speed; a universal testing
machine's crosshead accelerates over a finite time (``cardiosoft.actuation``: jerk-limited
ramps, ``ramp_time``). The paper gives the speed (3000 mm/min, section II-F) but no
acceleration, nor do the public data of the machine class (the INSTRON 5900 frames list speeds
up to 2500-3000 mm/min and no acceleration), so the ramp is scanned over 0-200 ms, peak
accelerations pi v_c / (2 t_r) of 0.4 m/s^2 and up. No value is fitted to the forces.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path
from typing import NamedTuple

import numpy as np

PUMPS = ("ss950-v3", "ss950-v4")
HEADS_MMHG = (30.0, 60.0, 90.0)
RAMPS_S = (0.0, 0.025, 0.05, 0.1, 0.2)
TUBE_MODULUS_PA = (2.2e6, 5.4e6)  # Shore 50A and 70A silicone by Gent's relation
TUBE_WALL_M = (1.5e-3, 3e-3)
SILICONE_LOSS_FACTOR = (0.05, 0.15)
FALL_AFTER_PEAK = 0.05  # a curve "falls after its peak" when it ends 5 % below it


def _bench(pump_name, **changes):
    """The pump's calibrated 30-bpm bench with the ideal crosshead (no ramp: ss950-v4's bench
    holds a 50-ms one, its prior's median), changed by ``changes``."""
    from cardiosoft.scene import load_scene

    scene = load_scene("bench-dynamic", pump=pump_name)
    return scene.replace(**({"bpm": 30.0, "ramp_time": 0.0} | changes))


class Ring(NamedTuple):
    """The bench linearised at one instant (SI but the frequency): module docstring."""

    frequency: float  # Hz
    damping_ratio: float
    chamber_compliance: float  # C_ch = 1 / (d2U/dV2), m^3/Pa
    column_compliance: float  # C_col = A_col / (rho g), m^3/Pa
    inertance: float  # L, Pa s^2/m^3

    @property
    def compliance(self) -> float:
        """C_ch and C_col in series (m^3/Pa)."""
        return 1.0 / (1.0 / self.chamber_compliance + 1.0 / self.column_compliance)


def linear_ring(scene, pump, traces, i) -> Ring:
    """The bench linearised at sample ``i`` of one member's ``traces`` (module docstring)."""
    import jax.numpy as jnp

    from cardiosoft.circulation import Tube
    from cardiosoft.units import RHO_WATER, G

    volume, pull = traces["volume"][i], traces["pull"][i]
    c_ch = 1.0 / float(pump.stiffness(jnp.asarray(volume), jnp.asarray(pull), scene.omega))
    area = 0.25 * np.pi * scene.column_diameter**2
    tube = Tube(scene.tube_length, scene.tube_diameter, loss_coefficient=scene.loss_coefficient)
    height = traces["node_pressure"][i] / (RHO_WATER * G)
    inertance = float(tube.line_inertance()) + RHO_WATER * height / area
    loss = float(tube.line_loss()) * 2.0 * abs(traces["outflow"][i])
    resistance = float(tube.line_resistance()) + loss
    ring = Ring(math.nan, math.nan, c_ch, area / (RHO_WATER * G), inertance)
    c = ring.compliance
    return ring._replace(
        frequency=1.0 / (2.0 * np.pi * np.sqrt(inertance * c)),
        damping_ratio=0.5 * resistance * np.sqrt(c / inertance),
    )


def _stiffnesses(scene, pump, traces, i) -> tuple[float, float]:
    """At sample ``i``: the chamber's stiffness k = d2U/dV2 and its zero-pressure elastance
    E(x), on which the viscoelastic branch's spring r E(x) stands (Pa/m^3)."""
    import jax.numpy as jnp

    volume, pull = jnp.asarray(traces["volume"][i]), jnp.asarray(traces["pull"][i])
    k = float(pump.stiffness(volume, pull, scene.omega))
    return k, float(pump.chamber_elastance(pull, scene.omega))


def branch_loss_factor(scene, pump, traces, i, f) -> float:
    """tan(delta) of the chamber with the calibrated viscoelastic branch (a standard linear
    solid, ``cardiosoft.circuit.ShellViscoelasticity``: spring r E(x) and time tau beside the
    chamber's stiffness k) at frequency f (Hz), at sample ``i``."""
    if not scene.has("shell_viscoelasticity"):
        return 0.0
    k, elastance = _stiffnesses(scene, pump, traces, i)
    branch = scene.viscoelastic_ratio * elastance
    wt = 2.0 * np.pi * f * scene.relaxation_time
    storage = k + branch * wt**2 / (1.0 + wt**2)
    return branch * wt / (1.0 + wt**2) / storage


def silicone_branch(scene, pump, traces, i, f, tan_delta) -> dict:
    """The viscoelastic branch of a silicone with loss factor ``tan_delta`` at frequency ``f``
    (Hz), in place of the calibrated one: the standard linear solid whose loss factor, beside
    the chamber's stiffness k at sample ``i``, peaks at ``tan_delta`` at ``f``. With the
    branch's spring ``b = r E(x)`` and ``w = 2 pi f tau``, ``tan(delta) = b w / (k (1 + w^2) +
    b w^2)`` peaks at ``w = 1 / s``, ``s = sqrt(1 + b / k)``, at ``(s^2 - 1) / (2 s)``; so
    ``s = t + sqrt(t^2 + 1)``. Returns the scene's ``viscoelastic_ratio`` and
    ``relaxation_time`` (s)."""
    k, elastance = _stiffnesses(scene, pump, traces, i)
    s = tan_delta + math.sqrt(tan_delta**2 + 1.0)
    return {
        "viscoelastic_ratio": (s**2 - 1.0) * k / elastance,
        "relaxation_time": 1.0 / (2.0 * math.pi * f * s),
    }


def candidates(scene, row) -> dict:
    """Orders of magnitude of candidates (c) and (d) at one run's ring (module docstring):
    ranges over :data:`TUBE_MODULUS_PA`, :data:`TUBE_WALL_M`, :data:`SILICONE_LOSS_FACTOR`."""
    from cardiosoft.units import MU_WATER, RHO_WATER, ml_per_mmHg

    ring = row["ring"]

    r, length = 0.5 * scene.tube_diameter, scene.tube_length
    e_t, wall = np.array(TUBE_MODULUS_PA), np.array(TUBE_WALL_M)
    stiff, soft = e_t[1] * wall[1], e_t[0] * wall[0]  # E_t h at the two ends
    c_tube = 2.0 * np.pi * r**3 * length / np.array([stiff, soft]) / ml_per_mmHg
    speed = np.sqrt(np.array([soft, stiff]) / (2.0 * RHO_WATER * r))
    alpha = r * np.sqrt(2.0 * np.pi * ring.frequency * RHO_WATER / MU_WATER)
    poiseuille = 8.0 * MU_WATER * length / (np.pi * r**4)
    unsteady = (alpha / (4.0 * np.sqrt(2.0)) - 1.0) * poiseuille  # beyond Poiseuille's (Pa s/m^3)
    zeta_womersley = 0.5 * unsteady * np.sqrt(ring.compliance / ring.inertance)
    # the chamber's share of the ring's strain energy: the stiffer of the two holds more
    share = ring.compliance / ring.chamber_compliance
    return {
        "tube_compliance_ml_per_mmHg": tuple(c_tube),
        "chamber_compliance_ml_per_mmHg": ring.chamber_compliance / ml_per_mmHg,
        "transit_ms": tuple(1e3 * length / speed[::-1]),
        "ring_period_ms": 1e3 / ring.frequency,
        "womersley": alpha,
        "zeta_unsteady_friction": zeta_womersley,
        "zeta_silicone": tuple(0.5 * np.array(SILICONE_LOSS_FACTOR) * share),
        "zeta_ring": ring.damping_ratio,
        "branch_loss_factor": row["loss_factor"],
        "zeta_branch": 0.5 * row["loss_factor"] * share,
    }


def candidates_table(scenes, rows) -> str:
    from cardiosoft.console import table

    header = [
        "pump",
        "tube C",
        "chamber C",
        "transit",
        "ring period",
        "alpha",
        "zeta: unsteady",
        "silicone",
        "the ring's",
        "branch tan d",
        "branch zeta",
    ]
    units = ["", "ml/mmHg", "ml/mmHg", "ms", "ms", "-", "friction", "loss", "", "at ring", ""]
    body = []
    for pump, row in rows.items():
        c = candidates(scenes[pump], row)
        body.append(
            [
                pump,
                "{:.3f}-{:.3f}".format(*c["tube_compliance_ml_per_mmHg"]),
                f"{c['chamber_compliance_ml_per_mmHg']:.3f}",
                "{:.0f}-{:.0f}".format(*c["transit_ms"]),
                f"{c['ring_period_ms']:.0f}",
                f"{c['womersley']:.0f}",
                f"+{c['zeta_unsteady_friction']:.4f}",
                "+{:.3f}-{:.3f}".format(*c["zeta_silicone"]),
                f"{c['zeta_ring']:.3f}",
                f"{c['branch_loss_factor']:.3f}",
                f"+{c['zeta_branch']:.3f}",
            ]
        )
    return table(header, units, body)


def diagnose(pump_name):
    """One row per afterload: the dicts of the module docstring's diagnosis, and the traces."""
    import jax

    from cardiosoft.batch import solve_beats
    from cardiosoft.pump import load
    from cardiosoft.static import column_stiffness, quasi_static_stroke
    from cardiosoft.units import RHO_WATER, G, mmHg

    scene, pump = _bench(pump_name), load(pump_name)
    heads = np.asarray(HEADS_MMHG) * mmHg
    out = solve_beats(scene, afterload=heads, save="traces", pump=pump)
    traces = {k: np.asarray(v) for k, v in out.traces.items()}
    k = column_stiffness(0.25 * np.pi * scene.column_diameter**2, RHO_WATER, G)
    length = scene.shortening * float(pump.cable_length(scene.omega))
    strokes = jax.jit(
        jax.vmap(lambda h: quasi_static_stroke(pump, scene.omega, length, h, k, n_points=201))
    )(heads)
    friction = np.exp(scene.cable_friction)  # the load cell's reading while pulling
    static = {"pull": np.asarray(strokes.x), "force": friction * np.asarray(strokes.force)}
    stroke = float(np.max(traces["pull"]))
    rows = []
    for m, head in enumerate(HEADS_MMHG):
        member = {k: v[m] for k, v in traces.items()}
        in_pull = np.flatnonzero(np.diff(member["pull"]) > 0)
        pulling = np.arange(in_pull[-1] + 2)
        i = int(pulling[np.argmax(member["cable_force"][pulling])])
        ring = linear_ring(scene, pump, member, i)
        force = member["cable_force"][pulling]
        slack = np.flatnonzero(member["volume"][pulling] <= float(pump.unloaded_volume))
        taut_until = float(member["pull"][slack[0]] / stroke) if slack.size else 1.0
        q_force, q_pull = static["force"][m], static["pull"][m]
        rows.append(
            {
                "pump": pump_name,
                "afterload_mmHg": head,
                "peak_force_N": float(member["cable_force"][i]),
                "peak_at_stroke": float(member["pull"][i] / stroke),
                "ring": ring,
                "falls_after_peak": bool(force[-1] < (1.0 - FALL_AFTER_PEAK) * force.max()),
                "static_peak_at_stroke": float(q_pull[np.argmax(q_force)] / stroke),
                "dynamic_sv_ml": float(out.metrics.stroke_volume[m]) / 1e-6,
                "taut_until": taut_until,
                "loss_factor": branch_loss_factor(scene, pump, member, i, ring.frequency),
                "silicone_branches": {
                    t: silicone_branch(scene, pump, member, i, ring.frequency, t)
                    for t in SILICONE_LOSS_FACTOR
                },
            }
        )
    return rows, traces, static


def simulated(pump_name, ring_row):
    """Peak forces (N) and dynamic SVs (ml) of the candidates simulated one at a time, then
    together: the crosshead's ramp times of :data:`RAMPS_S` and the raised-cosine pull (the same
    stroke and period), candidate (a); the silicone's loss factors of
    :data:`SILICONE_LOSS_FACTOR` at ``ring_row``'s ring in place of the calibrated branch
    (:func:`silicone_branch`), candidate (d); each of those with the ramp's prior median
    (50 ms, ``bench-dynamic.toml``). ``{label: (forces, svs)}``."""
    from cardiosoft.batch import solve_beats
    from cardiosoft.pump import load
    from cardiosoft.units import mmHg

    pump = load(pump_name)
    heads = np.asarray(HEADS_MMHG) * mmHg
    cases = {f"ramp {1e3 * r:.0f} ms": {"ramp_time": r} for r in RAMPS_S}
    cases["raised cosine"] = {"shape": "cosine"}
    for t, branch in ring_row["silicone_branches"].items():
        cases[f"silicone tan d {t:g}"] = branch
    for t, branch in ring_row["silicone_branches"].items():
        cases[f"ramp 50 ms + silicone {t:g}"] = branch | {"ramp_time": 0.05}
    results = {}
    for label, changes in cases.items():
        out = solve_beats(_bench(pump_name, **changes), afterload=heads, save="metrics", pump=pump)
        results[label] = (
            np.asarray(out.metrics.peak_force),
            np.asarray(out.metrics.stroke_volume) / 1e-6,
        )
    return results


def _paper():
    from cardiosoft import datasets

    bench = datasets.load_paper_data().fig10_bench
    return np.asarray(bench["peak_force_N"], float), np.asarray(bench["dynamic_sv_ml"], float)


def diagnosis_table(rows) -> str:
    from cardiosoft.console import table
    from cardiosoft.units import ml_per_mmHg

    paper_force, _ = _paper()
    header = [
        "pump",
        "afterload",
        "peak force",
        "paper",
        "at stroke",
        "ring",
        "zeta",
        "dV/dP",
        "falls after",
        "static peak",
        "taut until",
    ]
    units = ["", "mmHg", "N", "N", "-", "Hz", "-", "ml/mmHg", "peak", "at stroke", "stroke"]
    body = [
        [
            r["pump"],
            f"{r['afterload_mmHg']:g}",
            f"{r['peak_force_N']:.1f}",
            f"{paper_force[i % 3]:.1f}",
            f"{r['peak_at_stroke']:.2f}",
            f"{r['ring'].frequency:.2f}",
            f"{r['ring'].damping_ratio:.2f}",
            f"{r['ring'].chamber_compliance / ml_per_mmHg:.3f}",
            "yes" if r["falls_after_peak"] else "no",
            f"{r['static_peak_at_stroke']:.2f}",
            f"{r['taut_until']:.2f}",
        ]
        for i, r in enumerate(rows)
    ]
    return table(header, units, body)


def candidates_simulated_table(results_by_pump) -> str:
    """Each simulated candidate's peak forces and dynamic SVs, and their change from the pump's
    calibrated bench with the ideal crosshead (the ``ramp 0 ms`` row)."""
    from cardiosoft.console import table

    paper_force, paper_sv = _paper()
    header = ["pump", "candidate", "peak force 30/60/90", "change", "dynamic SV 30/60/90", "change"]
    units = ["", "", "N", "N", "ml", "ml"]
    joined = lambda values, fmt="{:.1f}": " / ".join(fmt.format(v) for v in values)  # noqa: E731
    body = [["paper", "", joined(paper_force), "", joined(paper_sv), ""]]
    for pump, results in results_by_pump.items():
        base_force, base_sv = results["ramp 0 ms"]
        for label, (force, sv) in results.items():
            body.append(
                [
                    pump,
                    label,
                    joined(force),
                    joined(force - base_force, "{:+.1f}"),
                    joined(sv),
                    joined(sv - base_sv, "{:+.1f}"),
                ]
            )
    return table(header, units, body)


def figure(path, diagnosed, results_by_pump):
    """Force-displacement at 30 bpm per pump (and the quasi-static pull, dashed), peaks
    marked; peak force against the ramp time, the paper's forces as lines."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from cardiosoft.files import atomic_path

    paper_force, _ = _paper()
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.5))
    colours = ("tab:blue", "tab:orange", "tab:green")
    for ax, (pump, (rows, traces, static)) in zip(axes[:2], diagnosed.items(), strict=True):
        for m, (row, colour) in enumerate(zip(rows, colours, strict=True)):
            pulling = np.diff(traces["pull"][m], prepend=-1.0) > 0
            x, force = traces["pull"][m][pulling] * 1e3, traces["cable_force"][m][pulling]
            ax.plot(x, force, color=colour, label=f"{row['afterload_mmHg']:g} mmHg, 30 bpm")
            ax.plot(static["pull"][m] * 1e3, static["force"][m], "--", color=colour, lw=1)
            ax.plot(x[np.argmax(force)], force.max(), "o", color=colour)
            ax.axhline(paper_force[m], color=colour, lw=0.6, ls=":")
        ax.set(
            title=f"{pump}: force-displacement (dashed: quasi-static; dotted: paper's peak)",
            xlabel="cable pull x (mm)",
            ylabel="cable force (N)",
        )
        ax.title.set_fontsize(9)
        ax.legend(fontsize=8)
    ax = axes[2]
    ramps = [1e3 * r for r in RAMPS_S]
    for pump, style in zip(results_by_pump, ("-o", "--s"), strict=True):
        results = results_by_pump[pump]
        forces = np.array([results[f"ramp {r:.0f} ms"][0] for r in ramps])
        for m, colour in enumerate(colours):
            ax.plot(
                ramps, forces[:, m], style, color=colour, label=f"{pump}, {HEADS_MMHG[m]:g} mmHg"
            )
    for m, colour in enumerate(colours):
        ax.axhline(paper_force[m], color=colour, lw=0.6, ls=":")
    ax.set(
        title="peak force against the crosshead's ramp time (30 bpm)",
        xlabel="ramp time (ms)",
        ylabel="peak force (N)",
    )
    ax.title.set_fontsize(9)
    ax.legend(fontsize=7)
    fig.tight_layout()
    with atomic_path(Path(path)) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m fit.ring", description=__doc__.split("\n")[0])
    parser.add_argument("--out", metavar="DIR", help="also write DIR/ring.png")
    parser.add_argument("--force", action="store_true", help="overwrite DIR/ring.png")
    args = parser.parse_args(argv)
    import jax

    jax.config.update("jax_enable_x64", True)
    from cardiosoft.files import refuse_overwrite

    out = None
    if args.out:
        out = Path(args.out) / "ring.png"
        try:
            refuse_overwrite(out, args.force)
        except ValueError as err:
            print(f"error: {err}", file=sys.stderr)
            return 2
    start = time.perf_counter()
    diagnosed, simulations = {}, {}
    for pump in PUMPS:
        print(f"{pump}: the 30-bpm beats and the ramp scan ...", file=sys.stderr)
        diagnosed[pump] = diagnose(pump)
        simulations[pump] = simulated(pump, diagnosed[pump][0][1])
    print("The ring at 30 bpm, the bench linearised at the instant of the peak force")
    print(diagnosis_table([row for rows, _, _ in diagnosed.values() for row in rows]))
    print("\nCandidates (c) and (d) at the 60-mmHg ring, orders of magnitude (module docstring)")
    scenes = {pump: _bench(pump) for pump in PUMPS}
    print(candidates_table(scenes, {pump: diagnosed[pump][0][1] for pump in PUMPS}))
    print(
        "\nThe candidates simulated: (a) the crosshead's jerk-limited ramps and the "
        "raised-cosine pull, (d) a silicone's loss at the 60-mmHg ring in place of the "
        "calibrated branch, and together"
    )
    print(candidates_simulated_table(simulations))
    if out is not None:
        out.parent.mkdir(parents=True, exist_ok=True)
        figure(out, diagnosed, simulations)
        print(f"wrote {out}", file=sys.stderr)
    print(f"done in {time.perf_counter() - start:.0f} s", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
