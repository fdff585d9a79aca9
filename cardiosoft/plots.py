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


def plot_fig10(result, path, records=None) -> None:
    """Fig. 10-style summary of a run: (a) SV vs afterload, (b) ejected volume vs time,
    (c) force vs cable displacement, (d) pressure-volume loop.

    ``records``: the run's summary records (``simulate``); where they hold 95 % predictive
    bands (``<metric>_band``, ``simulate --uncertainty``), (a) shades the SVs' bands and (c)
    marks each peak force's band."""
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
        _shade_bands(ax[0, 0], heads, records)
        ax[0, 0].set_xlabel("afterload [mmHg]")
        ax[0, 0].legend(fontsize=8)
    else:
        ax[0, 0].bar([m.label for m in members], [m.metrics["stroke_volume"] / ml for m in members])
        _bar_bands(ax[0, 0], [m.label for m in members], records)
    ax[0, 0].set_ylabel("stroke volume [ml]")
    ax[0, 0].set_title("(a) stroke volume", fontsize=10)
    for m in members:
        t = m.traces
        ejected = t.get("column_volume", t["volume"].max() - t["volume"])
        ax[0, 1].plot(t["time"], (ejected - ejected.min()) / ml, label=m.label)
        ax[1, 0].plot(t["pull"] / mm, t["cable_force"], label=m.label)
        ax[1, 1].plot(t["volume"] / ml, t["pump_pressure"] / mmHg, label=m.label)
    _force_bands(ax[1, 0], members, records)
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


BAND_KEYS = (("static_sv_ml", "C0", "static"), ("dynamic_sv_ml", "C1", "dynamic"))
"""Panel (a)'s shaded bands: record key, colour (as the lines'), label."""


def _bands(records, key):
    """The records' ``<key>_band`` as (low, high) arrays, or None where one is missing."""
    bands = [r.get(f"{key}_band") for r in records or ()]
    if not bands or any(b is None or None in b for b in bands):
        return None
    return np.array(bands, dtype=float).T


def _shade_bands(ax, heads, records) -> None:
    """Shade the SVs' 95 % predictive bands over the afterloads, where the records hold them."""
    for key, colour, label in BAND_KEYS:
        band = _bands(records, key)
        if band is not None:
            ax.fill_between(heads, *band, color=colour, alpha=0.2, lw=0,
                            label=f"{label}: 95 % band")


def _bar_bands(ax, labels, records) -> None:
    """The SV's 95 % predictive band as an error bar on each member's bar."""
    band = _bands(records, "dynamic_sv_ml")
    if band is not None:
        mid = 0.5 * (band[0] + band[1])
        ax.errorbar(labels, mid, yerr=0.5 * (band[1] - band[0]), fmt="none", color="k",
                    capsize=4, label="95 % band")
        ax.legend(fontsize=8)


def _force_bands(ax, members, records) -> None:
    """Mark each member's peak-force band at the pull where its force peaks."""
    from cardiosoft.units import mm

    for m, r in zip(members, records or (), strict=False):
        band = r.get("peak_force_N_band")
        if band is None or None in band:
            continue
        k = int(np.argmax(m.traces["cable_force"]))
        x = m.traces["pull"][k] / mm
        ax.plot([x, x], band, lw=3, alpha=0.4, solid_capstyle="butt")


def plot_closed_loop(result, path, native=None) -> None:
    """A closed-loop run (:func:`cardiosoft.run` of ``heart``, ``soft-lv``, ``soft-rv``,
    ``tah``): (a, b) the left and right ventricles' (or pumps') pressure-volume loops, over the
    native heart's when ``native`` (a run of ``heart``) is given; (c) the pressures of the aorta,
    the pulmonary artery and both atria over the beat; (d) the pumps' cable forces."""
    from cardiosoft.units import ml, mmHg

    plt = _pyplot()
    fig, ax = plt.subplots(2, 2, figsize=(9, 7), constrained_layout=True)
    pumps = set(result.scene.pumps)
    for m in (m for m in result.members if m.traces):
        t = m.traces
        for a, chamber, side in ((ax[0, 0], "lv", "left"), (ax[0, 1], "rv", "right")):
            what = "soft pump" if chamber in pumps else "native"
            a.plot(t[f"{chamber}_volume"] / ml, t[f"{chamber}_pressure"] / mmHg, label=what)
            a.set_title(f"({'a' if side == 'left' else 'b'}) {side} ventricle", fontsize=10)
        for name, label in (
            ("ar_sys", "aorta"),
            ("ar_pul", "pulmonary artery"),
            ("la", "left atrium"),
            ("ra", "right atrium"),
        ):
            ax[1, 0].plot(t["time"], t[f"{name}_pressure"] / mmHg, label=label)
        for chamber in sorted(pumps):
            ax[1, 1].plot(t["time"], t[f"{chamber}_cable_force"], label=f"{chamber.upper()} pump")
    if native is not None:
        for m in (m for m in native.members if m.traces):
            for a, chamber in ((ax[0, 0], "lv"), (ax[0, 1], "rv")):
                v, p = m.traces[f"{chamber}_volume"] / ml, m.traces[f"{chamber}_pressure"] / mmHg
                a.plot(v, p, "k--", lw=1, label="native heart")
    for a in (ax[0, 0], ax[0, 1]):
        a.set(xlabel="volume [ml]", ylabel="pressure [mmHg]")
        a.legend(fontsize=8)
    ax[1, 0].set(xlabel="time in the beat [s]", ylabel="pressure [mmHg]")
    ax[1, 0].set_title("(c) pressures over the last beat", fontsize=10)
    ax[1, 0].legend(fontsize=8)
    ax[1, 1].set(xlabel="time in the beat [s]", ylabel="cable force [N]")
    ax[1, 1].set_title("(d) cable forces", fontsize=10)
    if pumps:
        ax[1, 1].legend(fontsize=8)
    else:
        ax[1, 1].text(
            0.5, 0.5, "no soft pump", ha="center", va="center", transform=ax[1, 1].transAxes
        )
    s = result.scene
    fig.suptitle(f"{s.name}: closed loop at {s.bpm:g} bpm")
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format=check_figure_path(path), dpi=110)
    plt.close(fig)
