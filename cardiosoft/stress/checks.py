"""The checks of the hard-case suite (:func:`check_member`, for every case; with
:func:`check_loop_member` for a closed loop's), and what a case's outcome is
(:class:`Outcome`: passed, flagged, failed or a known failure)."""

from __future__ import annotations

import dataclasses
import fnmatch
import math
from collections.abc import Iterable

from cardiosoft.network.loop_batch import SIDES
from cardiosoft.network.loop_scene import LoopScene
from cardiosoft.pump import Domain
from cardiosoft.results import ENERGY_ROUNDOFF, MemberResult
from cardiosoft.stress.cases import Case
from cardiosoft.stress.loop_cases import LoopCase
from cardiosoft.units import ml, mmHg

__all__ = [
    "BALANCE_QUADRATURE",
    "ENERGY_TOLS",
    "KNOWN_FAILURES",
    "PUMP_FIELDS",
    "STATUSES",
    "VOLUME_TOL",
    "KnownFailure",
    "LoopView",
    "MemberView",
    "Outcome",
    "check_loop_member",
    "check_member",
    "flag_kinds",
    "known_reasons",
    "left_half_capacity",
    "outcome",
    "physical_problems",
]

VOLUME_TOL = 1e-9
"""Largest relative drift of the total fluid volume."""
ENERGY_TOLS = {"fast": (0.5, 1e-3), "default": (3e-2, 1e-4), "reference": (1e-6, 1e-8)}
"""Per accuracy preset, (rel, abs J): the account's closure |work in - delivered - lost -
stored change| must be at most rel times the energy the beat carries plus abs, i.e.
``energy_residual <= rel + abs / carried`` (``carried``: see
:attr:`cardiosoft.metrics.BeatMetrics.energy_residual`). The account is integrated with the
states at the preset's tolerances, so it closes to what they allow, not to round-off (about
the volume's error, atol in m^3, times the pressures, ~2e4 Pa, each step). Measured on this
suite's batches (solve_beats(energy=True) on plan()'s members; rel: the largest residual
where more than 1e-2 J is carried; abs: the largest closure where less is), then rounded up
by 2-7x:

- 'fast' (grid at 10, 60, 300 bpm): rel 0.22 (rv-pulmonary, 300 bpm, Omega 0.3, C 0.65),
  abs 3.1e-4 J (bench-dynamic, 300 bpm, C 0.01);
- 'default' (grid at 10, 60, 120, 300 bpm, stiff, valves, preload, long, the quick subset's
  draws): rel 1.4e-2 (500 beats of lv-systemic at 300 bpm; 1.6e-3 over the quick subset),
  abs 4.6e-5 J (stiff lv-systemic, resistances max, 300 bpm);
- 'reference' (grid at 10, 60, 300 bpm): rel 4.7e-7 (bench-dynamic, Omega 4, C 0.4, 150
  mmHg, 300 bpm: the period-2 swing, which reports not steady; 1.25e-6 of the work in alone
  before the account counted the energy the column gives back and the shell stores), abs
  1.4e-9 J (C 0.01, 300 bpm); rel is the issue's 1e-6.
"""

STATUSES = ("passed", "flagged", "failed", "known")


@dataclasses.dataclass(frozen=True)
class KnownFailure:
    """A failure of the library that is known and reported: a problem of ``check`` in a case
    whose id matches one of ``cases`` (``fnmatch`` patterns), and whose shortening C is at most
    ``max_shortening`` when that is given, is known. A case whose every problem is known is
    counted as known, not failed."""

    cases: tuple[str, ...]
    check: str
    reason: str
    max_shortening: float | None = None

    def covers(self, case: Case | LoopCase, check: str) -> bool:
        c = case.shortening  # None for a native closed loop: no pump, no shortening
        return (
            check == self.check
            and any(fnmatch.fnmatchcase(case.id, p) for p in self.cases)
            and (self.max_shortening is None or (c is not None and c <= self.max_shortening))
        )


# Known failures: each entry is a library bug, found by this suite and reported; the cases are
# printed as "known" with the reason, so that CI can run the suite while they stay visible.
# Remove an entry when its bug is fixed (the suite then counts the cases as passed again).
KNOWN_FAILURES: tuple[KnownFailure, ...] = ()


@dataclasses.dataclass(frozen=True)
class Outcome:
    """What the checks found for one case."""

    case: Case | LoopCase
    status: str
    """One of :data:`STATUSES`."""
    problems: tuple[tuple[str, str], ...] = ()
    """(check, what is wrong): why it failed."""
    notes: tuple[str, ...] = ()
    """Why it is flagged: the member's flags and messages."""
    known: tuple[str, ...] = ()
    """Reasons of the matching :data:`KNOWN_FAILURES`."""


def flag_kinds(flags: Iterable[str]) -> set[str]:
    """What the flags of :func:`cardiosoft.results.flags` cover, read from their wording."""
    kinds = set()
    for f in flags:
        if "pump pressure" in f or "extrapolat" in f:
            kinds.add("extrapolated")
        if "static" in f and ("pressure" in f or "extrapolat" in f):
            kinds.add("static extrapolated")
        if "cable force" in f:
            kinds.add("cable pushes")
        if f.startswith("efficiency"):
            kinds.add("efficiency")
        if f.startswith("static efficiency"):
            kinds.add("static efficiency")
        if f.startswith("energy account"):
            kinds.add("energy account")
        if f.startswith("energy efficiency"):
            kinds.add("energy efficiency")
    return kinds


def physical_problems(m: dict[str, float]) -> list[tuple[str, str, set[str]]]:
    """What of a member's metrics (SI, raw: before :func:`~cardiosoft.results.flags`) is not
    physical: (check, what, the flag kinds that excuse it) for each violation. A NaN violates
    nothing here: the finiteness check reports it.

    The checks are necessary conditions, not the model itself: a cavity volume is positive;
    SV = EDV - ESV >= 0 and so 0 <= EF <= 1; the cardiac output >= 0; a cable force >= 0
    everywhere makes the peak force and the work of the monotone pull >= 0 (a negative force is
    flagged); the reference pressure, a column head or the mean of a Windkessel node fed through
    a valve, is >= 0; the paper's efficiency lies in [0, 1] (else flagged). With the energy
    account, at the periodic steady state (kind ``"transient"`` excuses it): the energy
    efficiency, delivered / work in, lies in [0, 1] to within the account's own residual (the
    losses are >= 0 and the shell's stored energy comes back each beat).
    """
    out: list[tuple[str, str, set[str]]] = []

    def bad(violated: bool, check: str, what: str, *excuses: str):
        if violated:
            out.append((f"physical/{check}", what, set(excuses)))

    if "edv" in m:
        _beat_problems(m, bad)
        if m.get("energy_efficiency") is not None:
            _energy_problems(m, bad)
    if "static_stroke_volume" in m:
        _static_problems(m, bad)
    return out


def _outside(v, lo, hi) -> bool:
    return v < lo or v > hi


def _beat_problems(m: dict[str, float], bad) -> None:
    """Volumes, EF, cardiac output, pressures, force, work and efficiency of a beat."""
    edv, esv = m["edv"], m["esv"]
    volumes = f"EDV {edv:.6g}, ESV {esv:.6g} m^3"
    bad(edv <= 0 or esv <= 0, "volume", f"{volumes}: not positive", "extrapolated")
    bad(esv > edv or m["stroke_volume"] < 0, "volume", f"{volumes}: SV < 0")
    ef = m["ejection_fraction"]
    bad(_outside(ef, 0, 1), "ejection fraction", f"EF {ef:.6g} outside [0, 1]", "extrapolated")
    co = m["cardiac_output"]
    bad(co < 0, "cardiac output", f"cardiac output {co:.6g} m^3/s < 0")
    bad(m["min_pump_pressure"] > m["max_pump_pressure"], "pressure", "min pump pressure > max")
    f, w = m["peak_force"], m["mech_work"]
    bad(f < 0, "force", f"peak force {f:.6g} N < 0", "cable pushes")
    bad(w < -1e-12, "work", f"mechanical work {w:.6g} J < 0", "cable pushes")
    p = m["reference_pressure"]
    bad(p < -1e-6 * mmHg, "pressure", f"reference pressure {p / mmHg:.6g} mmHg < 0")
    e = m["efficiency"]
    bad(_outside(e, 0, 1), "efficiency", f"efficiency {e:.6g} outside [0, 1]", "efficiency")


def _energy_problems(m: dict[str, float], bad) -> None:
    """The energy efficiency in [0, 1] and the losses >= 0, to the account's own residual."""
    e = m["energy_efficiency"]
    slack = m.get("energy_residual", 0.0)
    slack = slack if math.isfinite(slack) else 0.0
    terms = {
        k: m.get(f"{k}_change" if k == "stored" else f"work_{k}", math.nan)
        for k in ("delivered", "in", "lost", "stored")
    }
    detail = "at the steady state (" + ", ".join(f"{k} {v:.4g} J" for k, v in terms.items()) + ")"
    # a cable that pushes turns the capstan friction into a negative loss: flagged
    excuses = ("transient", "cable pushes", "energy efficiency", "energy account")
    below = f"energy efficiency {e:.6g} < 0 {detail}"
    bad(e < -slack, "energy efficiency < 0", below, *excuses)
    above = f"energy efficiency {e:.6g} > 1 {detail}"
    bad(e > 1 + slack, "energy efficiency > 1", above, *excuses)
    lost, work_in = m.get("work_lost", 0.0), abs(m.get("work_in", 0.0))
    # the losses are what the account leaves of energies of the size of the shell's strain
    # energy U: a vanishing stroke's losses are round-off of U (hypothesis found -1.5e-16 J
    # with U ~ 0.5 J at C 1e-184), not a sign of an unphysical solve
    roundoff = ENERGY_ROUNDOFF * abs(m.get("stored_energy", 0.0))
    bad(
        lost < -(slack * work_in + roundoff),
        "losses",
        f"losses {lost:.4g} J < 0 (work in {work_in:.4g} J)",
        "cable pushes",
        "energy account",
    )


def _static_problems(m: dict[str, float], bad) -> None:
    """The quasi-static stroke's volume, force, work and efficiency."""
    sv, f = m["static_stroke_volume"], m["static_peak_force"]
    w, e = m["static_mech_work"], m["static_efficiency"]
    # round-off of the quasi-static root (V near 1e-4 m^3): 1e-9 ml
    bad(sv < -1e-15, "static", f"static stroke volume {sv:.6g} m^3 < 0")
    bad(f < 0, "static", f"static peak force {f:.6g} N < 0", "cable pushes")
    bad(w < -1e-12, "static", f"static mechanical work {w:.6g} J < 0", "cable pushes")
    bad(
        _outside(e, 0, 1),
        "static",
        f"static efficiency {e:.6g} outside [0, 1]",
        "static efficiency",
    )


@dataclasses.dataclass(frozen=True)
class MemberView:
    """What :func:`check_member` looks at: one member, as the public results give it."""

    raw: dict[str, float]
    """Metrics before :func:`~cardiosoft.results.flags` (SI), ``static_*`` included."""
    record: MemberResult
    succeeded: bool
    steady: bool
    static_pressure_mmHg: float | None = None
    """The quasi-static stroke's largest pressure, head plus column rise (mmHg)."""
    accuracy: str = "default"
    """The scene's accuracy preset: the energy account's bound (:data:`ENERGY_TOLS`)."""


def check_member(v: MemberView, domain: Domain | None = None) -> tuple[list, list]:
    """(problems, notes) of one member: see the module docstring. ``problems`` are
    ``(check, text)`` pairs; ``notes`` say why a member that passes is flagged."""
    domain = Domain() if domain is None else domain
    problems, notes = [], []
    r = v.record
    message = r.message
    failed = not v.succeeded
    if r.beats == 0 and message == "quasi-static":  # a static stroke: no solver, no beats
        failed = False
    elif failed:
        if message.startswith("solver failed"):
            notes.append(message)
        else:
            problems.append(("reported", f"solver failed but the message is {message!r}"))
    elif not v.steady:
        if "not steady" in message:
            notes.append(message)
        else:
            problems.append(
                ("steady", f"not steady (residual {r.residual:.3g}) but the message is {message!r}")
            )
    elif message != "ok":
        problems.append(("steady", f"solved and steady but the message is {message!r}"))
    if message != "quasi-static" and (
        r.ok != (message == "ok") or (r.ok and (failed or not v.steady))
    ):
        problems.append(("reported", f"ok = {r.ok} with message {message!r}"))
    kinds = flag_kinds(r.flags)
    # no NaN or inf, unless the solver failed and said so, or an efficiency flagged as such
    values = dict(v.raw)
    if message != "quasi-static":
        values |= {"residual": r.residual, "volume_drift": r.volume_drift}
    for key, value in values.items():
        if value is None or math.isfinite(value) or failed:
            continue
        if key in ("efficiency", "static_efficiency", "energy_efficiency") and (
            key.replace("_", " ") in kinds
        ):
            continue
        if key in ("energy_residual", "energy_efficiency") and "energy account" in kinds:
            continue
        problems.append(("finite", f"{key} = {value}"))
    if message != "quasi-static" and not failed and not r.volume_drift <= VOLUME_TOL:
        problems.append(
            ("volume", f"total volume drifts by {r.volume_drift:.3g} (relative) > {VOLUME_TOL:g}")
        )
    energy = v.raw.get("energy_residual")
    if energy is not None and not failed and "energy account" not in kinds:
        rel, abs_j = ENERGY_TOLS[v.accuracy]
        terms = ("work_in", "work_delivered", "work_lost", "stored_change")
        carried = 0.5 * sum(abs(v.raw[k]) for k in terms)
        if not energy <= rel + abs_j / carried:
            problems.append(
                (
                    "energy",
                    f"energy residual {energy:.3g} > {rel:g} + {abs_j:g} J / {carried:.4g} J "
                    f"carried ('{v.accuracy}'; work in {v.raw['work_in']:.6g} J)",
                )
            )
    if not failed:
        if not v.steady and message != "quasi-static":
            kinds.add("transient")
        for check, what, excuses in physical_problems(v.raw):
            if not excuses & kinds:
                problems.append((check, what))
        hi = domain.pressure_mmHg[1]
        p = v.static_pressure_mmHg
        if p is not None and p > hi and "static extrapolated" not in kinds:
            problems.append(
                (
                    "extrapolated",
                    f"quasi-static stroke up to {p:.2f} mmHg (head "
                    f"+ column rise), above the fitted {hi:g} mmHg, not flagged",
                )
            )
    notes += list(r.flags)
    return problems, notes


PUMP_FIELDS = ("peak_force", "min_cable_force", "cable_work", "efficiency")
"""A closed-loop side's pump fields (:class:`~cardiosoft.network.loop_batch.SideMetrics`): NaN, by
definition, for a native ventricle."""
BALANCE_QUADRATURE = 5e-6
"""Relative error allowed for the trapezoid's means of the arterial flows
(:attr:`~cardiosoft.network.loop_batch.SideMetrics.net_output`, over
:data:`~cardiosoft.network.loop_batch.LOOP_SAMPLES` samples of the beat). Estimated by halving the
samples, |T(h) - T(2h)| (three times Richardson's estimate of a second-order error, and a
bound of a first-order one too, for the flows' kinks), it was at most 7.6e-7 of the output
over 134 steady members of the ``closed_loop`` group (save="traces": heart at every rate;
soft-lv and soft-rv at the corners at 40, 90, 180 bpm; tah at 60 and 120 bpm together and
opposite, at 180 together; the largest tah 60 bpm, left Omega 4, C 0.01, right Omega 0.3, C
0.65); rounded up 6x. It is small beside the cycle change's share, ~1e-3 of the output at
``steady_tol``, which alone held every measured gap with 3.5x to spare (the largest, 0.28 of
it, heart at 180 bpm) (measured 2026-12)."""


@dataclasses.dataclass(frozen=True)
class LoopView:
    """What :func:`check_loop_member` looks at: one member of a closed loop."""

    member: MemberView
    """Its flat metrics (``raw``: ``"{side}_{field}"`` of
    :class:`~cardiosoft.network.loop_batch.LoopMetrics`, SI) and its record
    (:func:`cardiosoft.network.loop_results.loop_member_results`, the closed loop's flags)."""
    pump_sides: tuple[str, ...]
    """The sides (``"left"``, ``"right"``) whose ventricle is a soft pump."""
    period: float
    """The beat (s)."""
    capacity: float
    """:func:`left_half_capacity` of the scene (m^3 per unit of cycle change)."""


def left_half_capacity(scene: LoopScene) -> float:
    """How much blood (m^3) the left half of the loop (pulmonary veins, left atrium, left
    ventricle, systemic arteries) can gain over a beat per unit of the beat's cycle change
    (:data:`cardiosoft.periodic.PERIODIC_SCALES`: a chamber's volume changes by at most that many
    ml, a vessel's pressure by that many mmHg, so its volume C p by C times that many mmHg)."""
    return 2 * ml + (scene.ar_sys.compliance + scene.ven_pul.compliance) * mmHg


def check_loop_member(v: LoopView, domain: Domain | None = None) -> tuple[list, list]:
    """(problems, notes) of one closed-loop member: :func:`check_member` 's checks (finite,
    volume, steadiness said; the closed loop's flags are notes), a native side's pump fields
    NaN (by definition, not a failure; a finite one is), and at the steady state the left and
    right net outputs equal to within what the beat's cycle change allows.

    The left half of the loop gains over a beat of period T what the pulmonary arteries pass
    into it less what the systemic arteries pass out: (net right - net left) T is its volume
    change, at most the member's ``residual`` times :func:`left_half_capacity` (exactly zero
    on the periodic orbit). So |net left - net right| <= residual capacity / T plus
    :data:`BALANCE_QUADRATURE` of the larger for the trapezoid's means; at the scene's
    ``steady_tol`` 0.01 that is 0.19 ml a beat for the shipped loops (0.58 ml/s at 180 bpm,
    against net outputs of 13-128 ml/s)."""
    raw = dict(v.member.raw)
    problems = []
    for side in SIDES:
        if side in v.pump_sides:
            continue
        for field in PUMP_FIELDS:
            value = raw.pop(f"{side}_{field}", math.nan)
            if not math.isnan(value):
                problems.append(("native", f"{side}_{field} = {value:.6g} on a native side"))
    more, notes = check_member(dataclasses.replace(v.member, raw=raw), domain)
    problems += more
    if v.member.succeeded and v.member.steady:
        problems += _balance_problems(v)
    return problems, notes


def _balance_problems(v: LoopView) -> list[tuple[str, str]]:
    left, right = v.member.raw["left_net_output"], v.member.raw["right_net_output"]
    if not (math.isfinite(left) and math.isfinite(right)):
        return []  # the finiteness check reports it
    residual = v.member.record.residual
    allowed = v.capacity * residual / v.period + BALANCE_QUADRATURE * max(abs(left), abs(right))
    gap = abs(left - right)
    if gap <= allowed:
        return []
    return [
        (
            "balance",
            f"net outputs left {left / ml:.6g}, right {right / ml:.6g} ml/s differ by "
            f"{gap / ml:.3g} ml/s at the steady state, more than the {allowed / ml:.3g} ml/s "
            f"its cycle change {residual:.3g} allows",
        )
    ]


def known_reasons(case: Case | LoopCase, problems) -> tuple[str, ...]:
    """Reasons of the known failures covering every problem; () unless all are covered."""
    reasons = []
    for check, _ in problems:
        match = [k for k in KNOWN_FAILURES if k.covers(case, check)]
        if not match:
            return ()
        reasons.append(match[0].reason)
    return tuple(dict.fromkeys(reasons))


def outcome(case: Case | LoopCase, problems, notes) -> Outcome:
    problems, notes = tuple(problems), tuple(notes)
    if problems:
        known = known_reasons(case, problems)
        return Outcome(case, "known" if known else "failed", problems, notes, known)
    return Outcome(case, "flagged" if notes else "passed", (), notes)
