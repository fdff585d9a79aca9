"""The contexts of use (ASME V&V 40, section 5): the questions the model is built to answer,
the decision each informs, and the risk that sets how much credibility each needs."""

from __future__ import annotations

from pathlib import Path

from cardiosoft.credibility.evidence import Section

__all__ = ["CONTEXTS", "context_of_use"]

CONTEXTS = (
    (
        "The bench",
        "What stroke volume, peak cable force, work and efficiency does a pump give on the "
        "paper's water-column bench, at a rate and an afterload? (`cardiosoft simulate`)",
        "Sizing the actuator and the rig before a bench run.",
        "Medium influence (the bench run follows and measures the same numbers); low "
        "consequence (a bench run is repeated at little cost).",
    ),
    (
        "A design for target SVs",
        "Which helix parameter Omega and cable shortening C give target stroke volumes at "
        "given rates and afterloads, with the least force? (`cardiosoft design`)",
        "Which prototype to mould next.",
        "High influence (the model chooses the design before anything is built); medium "
        "consequence (a wrong choice costs a moulding cycle).",
    ),
    (
        "The pump in a circulation",
        "Does the pump, as left or right ventricle or both, in a closed circulation or a "
        "user's svZeroDSolver model, give a cardiac output and atrial pressures in range? "
        "(`cardiosoft simulate --scene soft-lv`, `--pump-chamber`)",
        "Whether to take a design to a mock circulatory loop.",
        "High influence (no circulation was measured with this pump: the model is the only "
        "evidence); medium consequence (a mock-loop test, not a patient, follows).",
    ),
)
"""(name, question, decision, risk) of each context of use."""


def context_of_use(folder: Path, quick: bool, progress) -> Section:
    """The contexts of use as a table (no checks: they are what the checks are for)."""
    rows = ["| context | question | decision it informs | model risk |", "|---|---|---|---|"]
    rows += [f"| {name} | {q} | {d} | {r} |" for name, q, d, r in CONTEXTS]
    text = "\n".join([
        "The model risk of each context is its influence on the decision times the "
        "consequence of a wrong decision (V&V 40): the higher it is, the more of the evidence "
        "below it needs. None of these contexts is a clinical decision: the pump is a "
        "ventricle *simulator* for the bench and the mock loop.",
        "",
        *rows,
    ])  # fmt: skip
    return Section("context_of_use", "Context of use", text)
