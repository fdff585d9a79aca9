"""Figures in the style of the paper. Matplotlib is imported lazily and drawn off-screen."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from cardiosoft._cli import atomic_path

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
