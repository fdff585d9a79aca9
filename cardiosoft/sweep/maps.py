"""Heat maps of a sweep: per afterload and rate, stroke volume, efficiency and peak force over
Omega x C (a closed loop: a pump's stroke volume, the cardiac output and the pump's peak force),
with the paper's Table I designs and the buckling onset marked."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np

__all__ = ["PANELS", "cell_edges", "map_keys", "map_name", "panels_of", "plot_maps"]


def cell_edges(values) -> np.ndarray:
    """The edges of the cells centred on ``values`` (a single value: a cell 0.1 wide)."""
    v = np.asarray(values, dtype=float)
    if len(v) == 1:
        return np.array([v[0] - 0.05, v[0] + 0.05])
    mid = 0.5 * (v[1:] + v[:-1])
    return np.concatenate([[2 * v[0] - mid[0]], mid, [2 * v[-1] - mid[-1]]])


def map_name(afterload_mmHg: float | None, bpm: float) -> str:
    """The file name of the map at one afterload (None: a Windkessel scene) and rate."""
    head = "" if afterload_mmHg is None else f"{afterload_mmHg:g}mmHg-"
    return f"map-{head}{bpm:g}bpm.png"


def map_keys(coords: dict) -> list[tuple[float | None, float]]:
    """(afterload or None, bpm) of each map of a sweep with these coordinates."""
    heads = coords.get("afterload_mmHg", (None,))
    return list(itertools.product(heads, coords["bpm"]))


PANELS = (
    ("stroke_volume_ml", "stroke volume [ml]", "viridis"),
    ("efficiency", "efficiency P_a SV / M [-]", "magma"),
    ("peak_force_N", "peak cable force [N]", "cividis"),
)
"""The three panels of an open-loop scene's map: (variable, label, colour map). A closed
loop's are its kind's (:func:`cardiosoft.network.closed_loop_tools.sweep_panels`)."""


def panels_of(ds) -> tuple:
    """The map panels a sweep's Dataset names (its attribute ``map_panels``; :data:`PANELS` for
    a file written before it had one)."""
    import json

    if "map_panels" not in ds.attrs:
        return PANELS
    return tuple(tuple(p) for p in json.loads(ds.attrs["map_panels"]))


def plot_maps(ds, out_dir, onset_twist: float | None = None) -> list[Path]:
    """One figure per afterload and bpm: stroke volume, efficiency and peak force over Omega x
    C, with the paper's Table I designs and the buckling onset ``Omega C = onset_twist``
    (default: :data:`cardiosoft.pump.BUCKLING_ONSET`) marked; points that are not steady are
    crossed. Files are named by :func:`map_name`, each written whole; returns their paths."""
    import matplotlib

    from cardiosoft.files import atomic_path
    from cardiosoft.pump import BUCKLING_ONSET

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    twist = BUCKLING_ONSET[0] if onset_twist is None else onset_twist
    written = []
    panels = panels_of(ds)
    coords = {d: tuple(np.asarray(ds[d]).tolist()) for d in ds.dims}
    for head, rate in map_keys(coords):
        sel = {"bpm": rate} | ({} if head is None else {"afterload_mmHg": head})
        cut = ds[[p[0] for p in panels] + ["steady"]].sel(sel).load()
        fig = _map_figure(plt, cut, panels, twist)
        where = "" if head is None else f"{head:g} mmHg, "
        steady = np.asarray(cut["steady"])
        fig.suptitle(
            f"{ds.attrs.get('scene', '')}: {where}{rate:g} bpm ({int(steady.sum())} of "
            f"{steady.size} points steady)"
        )
        path = Path(out_dir) / map_name(head, rate)
        try:
            with atomic_path(path) as tmp:
                fig.savefig(tmp, format="png", dpi=110, bbox_inches="tight")
        finally:
            plt.close(fig)
        written.append(path)
    return written


def _map_figure(plt, cut, panels, twist: float):
    """The three panels of one afterload and rate (``cut``: its Dataset over Omega x C)."""
    omega, c = np.asarray(cut["omega"]), np.asarray(cut["shortening"])
    x_edges, y_edges = cell_edges(omega), cell_edges(c)
    steady = np.asarray(cut["steady"].transpose("omega", "shortening"))
    fig, axes = plt.subplots(1, 3, figsize=(14, 4.3), constrained_layout=True)
    for ax, (name, label, cmap) in zip(axes, panels, strict=True):
        z = np.asarray(cut[name].transpose("omega", "shortening"), dtype=float)
        mesh = ax.pcolormesh(x_edges, y_edges, z.T, cmap=cmap, shading="flat")
        bar = fig.colorbar(mesh, ax=ax, label=label)
        if min(z.shape) >= 3 and np.isfinite(z).sum() >= 9:  # contours crowd at the step
            lines = ax.contour(omega, c, z.T, levels=8, colors="k", linewidths=0.5)
            bar.add_lines(lines)
        _marks(ax, omega, c, steady, x_edges, y_edges, twist)
        ax.set_title(label.split(" [")[0])
    handles, labels = axes[0].get_legend_handles_labels()
    if handles:
        fig.legend(
            handles,
            labels,
            loc="lower center",
            ncol=3,
            fontsize=8,
            frameon=False,
            bbox_to_anchor=(0.5, -0.08),
        )
    return fig


def _marks(ax, omega, c, steady, x_edges, y_edges, twist: float) -> None:
    """Points not steady, the buckling onset and the paper's Table I designs, over a panel."""
    from matplotlib import patheffects

    from cardiosoft.datasets import load_paper_data

    table1 = load_paper_data().table1_fem
    inside = (
        (table1["omega"] >= x_edges[0])
        & (table1["omega"] <= x_edges[-1])
        & (table1["shortening"] >= y_edges[0])
        & (table1["shortening"] <= y_edges[-1])
    )
    if (~steady).any():
        oo, cc = np.meshgrid(omega, c, indexing="ij")
        ax.plot(oo[~steady], cc[~steady], "x", color="0.6", ms=3, label="not steady")
    o_line = np.linspace(max(x_edges[0], 1e-9), x_edges[-1], 400)
    c_line = twist / o_line
    c_line[(c_line < y_edges[0]) | (c_line > y_edges[-1])] = np.nan
    if np.isfinite(c_line).any():
        ax.plot(
            o_line,
            c_line,
            "w--",
            lw=1.6,
            path_effects=[patheffects.withStroke(linewidth=3, foreground="k")],
            label=f"buckling onset Omega C = {twist:g}",
        )
    if inside.any():
        ax.plot(
            table1["omega"][inside],
            table1["shortening"][inside],
            "o",
            mfc="none",
            mec="red",
            ms=6,
            label="paper Table I designs",
        )
    ax.set_xlim(x_edges[0], x_edges[-1])
    ax.set_ylim(y_edges[0], y_edges[-1])
    ax.set_xlabel("helix parameter Omega [-]")
    ax.set_ylabel("cable shortening C [-]")
