"""The design figure: the search over a map of stroke volume in the (Omega, C) plane, Table I's
designs marked, and the Pareto trace.
"""

from __future__ import annotations

import numpy as np

from cardiosoft.design.result import DesignResult
from cardiosoft.design.search import REFINE

__all__ = ["plot_design", "sv_map"]


def plot_design(result: DesignResult, path=None):
    """The search over a map of stroke volume in the (Omega, C) plane, Table I's designs marked.

    The map is the result's :attr:`~DesignResult.sv_map` (``optimise(..., map_lattice=...)``),
    else interpolated from the designs the search evaluated; it is that of the first target.
    A second panel shows the Pareto trace when the result has one. With ``path`` (png, pdf or
    svg) the figure is written there, off-screen, and closed; without, it is returned (a
    notebook shows it).
    """
    from cardiosoft.files import atomic_path
    from cardiosoft.plots import check_figure_path

    fmt = None if path is None else check_figure_path(path)
    panels = 2 if result.pareto else 1
    size = (6.2 * panels, 5)
    if path is None:  # pyplot's figure: a notebook shows it
        import matplotlib.pyplot as plt

        fig, axes = plt.subplots(1, panels, figsize=size, constrained_layout=True)
    else:  # off-screen, whatever pyplot's backend is
        from matplotlib.figure import Figure

        fig = Figure(figsize=size, layout="constrained")
        axes = fig.subplots(1, panels)
    axes = np.atleast_1d(axes)
    _map_panel(fig, axes[0], result)
    if result.pareto:
        _pareto_panel(axes[1], result)
    if path is None:
        return fig
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format=fmt, dpi=110)
    return None


def _map_panel(fig, ax, result: DesignResult) -> None:
    """Stroke volume over (Omega, C), the target's contour, Table I, the search's path."""
    from cardiosoft.datasets import load_paper_data

    target = result.targets[0]
    contour = result.sv_map
    if contour is not None:
        om, c = np.meshgrid(contour["omega"], contour["shortening"], indexing="ij")
        sv = contour["sv_ml"][..., 0]
        filled = ax.contourf(om, c, sv, levels=16, cmap="viridis")
        ax.contour(om, c, sv, levels=[target.target_sv_ml], colors="w", linewidths=2)
    else:
        e = result.explored
        good = e["ok"]
        filled = ax.tricontourf(
            e["omega"][good], e["shortening"][good], e["sv_ml"][good, 0], levels=16, cmap="viridis"
        )
        ax.tricontour(
            e["omega"][good],
            e["shortening"][good],
            e["sv_ml"][good, 0],
            levels=[target.target_sv_ml],
            colors="w",
            linewidths=2,
        )
    where = f" at {target.afterload_mmHg:g} mmHg" if target.afterload_mmHg is not None else ""
    fig.colorbar(filled, ax=ax, label=f"stroke volume{where}, {target.bpm:g} bpm [ml]")
    table1 = load_paper_data().table1_fem
    ax.plot(table1["omega"], table1["shortening"], "k+", ms=8, label="paper Table I (FEM sweep)")
    e = result.explored
    ax.plot(e["omega"], e["shortening"], ".", color="0.85", ms=3, label="designs evaluated")
    p_om = [p["omega"] for p in result.path]
    p_c = [p["shortening"] for p in result.path]
    ax.plot(p_om, p_c, "o-", color="tab:red", ms=4, label="optimiser path")
    ax.plot(p_om[:1], p_c[:1], "s", color="tab:red", ms=7)
    ax.plot(
        [result.omega],
        [result.shortening],
        "*",
        color="tab:orange",
        ms=16,
        mec="k",
        label=f"design: Omega {result.omega:.3f}, C {result.shortening:.3f}",
    )
    if result.pareto:
        front = [p for p in result.pareto if not p.dominated]
        ax.plot(
            [p.omega for p in result.pareto],
            [p.shortening for p in result.pareto],
            "D",
            mfc="none",
            mec="tab:cyan",
            label="designs hitting the target (Pareto trace)",
        )
        ax.plot([p.omega for p in front], [p.shortening for p in front], "D", color="tab:cyan")
    ax.set(xlabel="helix parameter Omega [-]", ylabel="cable shortening C [-]")
    ax.set_title(
        f"{result.scene.name}: target {target.target_sv_ml:.1f} ml{where}"
        + ("" if result.reached else " (not reached)"),
        fontsize=10,
    )
    ax.legend(fontsize=7, loc="lower right")


def _pareto_panel(ax2, result: DesignResult) -> None:
    """Peak force against efficiency (or mechanical work) of the designs on the trace."""
    trade = "mech_work" if result.objective == "mech_work" else "efficiency"
    key = "mech_work_J" if trade == "mech_work" else "efficiency"
    pts = sorted(result.pareto, key=lambda p: p.peak_force_N)
    for p in pts:
        ax2.plot(p.peak_force_N, getattr(p, key), "o", color="0.6" if p.dominated else "tab:cyan")
        ax2.annotate(f"{p.omega:.2f}", (p.peak_force_N, getattr(p, key)), fontsize=7)
    front = [p for p in pts if not p.dominated]
    ax2.plot(
        [p.peak_force_N for p in front],
        [getattr(p, key) for p in front],
        "-",
        color="tab:cyan",
        label="non-dominated (labels: Omega)",
    )
    ax2.set(
        xlabel="peak cable force (mean over targets) [N]",
        ylabel="efficiency [-]" if trade == "efficiency" else "mechanical work [J]",
    )
    ax2.set_title("designs that hit the target: force against " + trade, fontsize=10)
    ax2.legend(fontsize=7)


def sv_map(problem, evaluate, design, lattice) -> dict:
    """Stroke volumes (ml, search accuracy) on an (Omega, C) lattice over the bounds, the other
    variables at ``design``; for the figure. Batches of :data:`REFINE` (the compiled shape)."""
    names = problem.space.names
    n_omega, n_c = lattice
    axes = {}
    for name, n in (("omega", n_omega), ("shortening", n_c)):
        j = names.index(name)
        lo, hi = problem.space.lo[j], problem.space.hi[j]
        axes[name] = lo + (hi - lo) * np.linspace(0.01, 0.99, n)
    om, c = np.meshgrid(axes["omega"], axes["shortening"], indexing="ij")
    z = np.array(
        [
            problem.space.to_z(design | {"omega": float(a), "shortening": float(b)}, problem.base)
            for a, b in zip(om.ravel(), c.ravel(), strict=True)
        ]
    )
    pad = (-len(z)) % REFINE
    z = np.concatenate([z, np.repeat(z[-1:], pad, axis=0)])
    sv = []
    for k in range(0, len(z), REFINE):
        values, _, ok, _ = evaluate(z[k : k + REFINE])
        sv.append(np.where(ok, values[..., 0], np.nan))
    sv = np.concatenate(sv)[: om.size].reshape(n_omega, n_c, -1)
    return {"omega": axes["omega"], "shortening": axes["shortening"], "sv_ml": sv}
