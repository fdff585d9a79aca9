"""Figures in the style of the paper. Matplotlib is imported lazily and drawn off-screen."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from cardiosoft.files import atomic_path

FIGURE_FORMATS = ("png", "pdf", "svg")


def check_figure_path(path) -> str:
    """The figure format from ``path``'s extension; ``ValueError`` if it is not supported."""
    fmt = Path(path).suffix.lstrip(".").lower()
    if fmt not in FIGURE_FORMATS:
        raise ValueError(
            f"figure file {path}: extension {fmt or '(none)'!r} is not one of "
            f"{', '.join(FIGURE_FORMATS)}"
        )
    return fmt


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_apex_motion(omegas, shortenings, dz_mm, dalpha_deg, path) -> None:
    """Fig. 7(a): apex translation (mm, top) and rotation (deg, bottom) against C, per Omega."""
    plt = _pyplot()
    fig, axes = plt.subplots(2, 1, figsize=(5, 6), sharex=True, constrained_layout=True)
    for j, omega in enumerate(omegas):
        axes[0].plot(shortenings, np.asarray(dz_mm)[:, j], "o-", label=f"Omega = {omega:g}")
        axes[1].plot(shortenings, np.asarray(dalpha_deg)[:, j], "o-")
    axes[0].set_ylabel("axial translation |dz| [mm]")
    axes[1].set_ylabel("axial rotation |dalpha| [deg]")
    axes[1].set_xlabel("shortening C [-]")
    axes[0].legend(fontsize=8, ncol=2)
    fig.suptitle("Geometrical model (paper Fig. 7(a))")
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format=check_figure_path(path))
    plt.close(fig)


def plot_fig10(result, path) -> None:
    """Fig. 10-style summary of a run: (a) SV vs afterload, (b) ejected volume vs time,
    (c) force vs cable displacement, (d) pressure-volume loop."""
    from cardiosoft.units import ml, mm, mmHg

    plt = _pyplot()
    fig, ax = plt.subplots(2, 2, figsize=(9, 7), constrained_layout=True)
    members = [m for m in result.members if m.traces]
    heads = [m.afterload / mmHg for m in result.members if m.afterload is not None]
    if heads:
        static = [m.metrics.get("static_stroke_volume", np.nan) / ml for m in result.members]
        ax[0, 0].plot(heads, static, "s-", label="static (quasi-static pull)")
        if members:
            ax[0, 0].plot(
                heads,
                [m.metrics["stroke_volume"] / ml for m in result.members],
                "o-",
                label="dynamic (peak column rise)",
            )
        ax[0, 0].set_xlabel("afterload [mmHg]")
        ax[0, 0].legend(fontsize=8)
    else:
        ax[0, 0].bar([m.label for m in members], [m.metrics["stroke_volume"] / ml for m in members])
    ax[0, 0].set_ylabel("stroke volume [ml]")
    ax[0, 0].set_title("(a) stroke volume", fontsize=10)
    for m in members:
        t = m.traces
        ejected = t.get("column_volume", t["volume"].max() - t["volume"])
        ax[0, 1].plot(t["time"], (ejected - ejected.min()) / ml, label=m.label)
        ax[1, 0].plot(t["pull"] / mm, t["cable_force"], label=m.label)
        ax[1, 1].plot(t["volume"] / ml, t["pump_pressure"] / mmHg, label=m.label)
    ax[0, 1].set(xlabel="time in the beat [s]", ylabel="ejected volume [ml]")
    ax[0, 1].set_title("(b) ejected volume, last beat", fontsize=10)
    ax[1, 0].set(xlabel="cable displacement [mm]", ylabel="cable force [N]")
    ax[1, 0].set_title("(c) force-displacement", fontsize=10)
    ax[1, 1].set(xlabel="pump volume [ml]", ylabel="pump pressure [mmHg]")
    ax[1, 1].set_title("(d) pressure-volume loop", fontsize=10)
    for a in (ax[0, 1], ax[1, 0], ax[1, 1]):
        a.legend(fontsize=8)
    s = result.scene
    fig.suptitle(f"{s.name}: Omega {s.omega:g}, C {s.shortening:g}, {s.bpm:g} bpm")
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format=check_figure_path(path), dpi=110)
    plt.close(fig)
