"""The hard-case suite (issue #14): every shipped scene pushed to the edges of what it allows.

    cardiosoft stress --quick     # the CI subset (tests/test_stress.py runs it)
    cardiosoft stress             # everything (long: see --help to pick a part)

(``python -m cardiosoft.stress`` is the same command.)

**Cases.** Each group is a list of batches; a batch is one call of the public batch solve
(:func:`cardiosoft.batch.solve_beats`, or :func:`~cardiosoft.batch.solve_static` for the static
scene, :func:`~cardiosoft.network.loop_batch.solve_loop` for a closed loop), its members the cases.
Members of one batch share the scene's numbers and, so that the whole suite compiles a
handful of functions, every batch of one scene structure has the same size (the 12 design
corners, times the two column heads of a water-column scene):

- ``grid``: every shipped scene x bpm :data:`GRID_BPMS` x the design corners (Omega
  :data:`GRID_OMEGAS` x C :data:`GRID_SHORTENINGS`) x the column heads
  :data:`GRID_AFTERLOADS_MMHG` (water-column scenes; a Windkessel scene has no head to set) x
  the accuracy presets. The static scene integrates no ODE: its rate and preset play no part,
  so it is one batch of designs x heads.
- ``stiff``: the stiffest afterloads the scene files allow: the bench's column at its narrowest
  (its compliance at the validated minimum), the tube at its longest and narrowest and the exit
  loss at its largest; a Windkessel's compliance at its validated minimum and every
  resistance (Rp, Rd, both valves) at its maximum, each alone and together.
- ``valves``: sharp valves, smoothing :data:`SHARP_SMOOTHING_MMHG` and ideal diodes.
- ``preload``: atrial pressures :data:`PRELOADS_MMHG`.
- ``long``: :data:`LONG_BEATS`-beat runs (a fixed number of beats; the steady-state check
  still applies to the last one).
- ``shooting``: the fastest rates with Newton shooting (``steady="shooting"``).
- ``property``: hypothesis draws the scene's numbers (actuation fractions, the bench's column,
  tube, loss, friction and viscoelasticity; the Windkessel, venous and atrial pressures,
  valves) and each member's Omega, C, bpm and column head over their whole allowed ranges
  (:data:`cardiosoft.scene.RANGES`), edges and odd values included, not only round ones.
- ``cli``: members of the grid run again through ``python -m cardiosoft.simulate`` (its
  ``main()``, in this process) and through the API with the same settings; ``summary.json``
  must equal the API's :func:`~cardiosoft.results.summary_records`, its ``flags`` the records'
  flags, and the exit status must say what the records say (1 when a member is not ok; flags
  alone leave it 0).
- ``closed_loop``: the closed-loop scenes (``heart``, ``soft-lv``, ``soft-rv``, ``tah``;
  :func:`cardiosoft.network.loop_batch.solve_loop`, the members the scene's numbers by path) at the
  rates :data:`LOOP_BPMS`, 40-180 bpm: the native ``heart`` at every rate in one batch; a
  scene with soft pumps per rate at the design corners (every pump at the same corner: the
  scenes' own design, Omega 4, C 0.4, is one) and, for ``tah``'s two pumps, at opposite
  corners too (left at a corner, right at the one across the grid: left weak and right
  strong, and the reverse). Only this group runs the closed loops; ``--scene`` and ``--bpm``
  narrow it as they narrow the others.
- ``models``: the soft pump in an svZeroDSolver model (:mod:`cardiosoft.stress.model_cases`):
  ``heart`` written as one (``cardiosoft export --svzerod``), the pump in place of each
  ventricle at the design corners, solved by the network to the periodic steady state; its
  own checks (the solve, finite records, the pump's volumes, EF and force, and its energy
  balance: the cables' work equals the stroke work over a beat).

**Checks** (:func:`check_member`), for every case:

- no NaN or inf in a metric, the residual or the volume drift, unless the member reports that
  its solver failed, or the value is an efficiency flagged as not meaningful;
- the total fluid volume conserved to :data:`VOLUME_TOL` (relative);
- the energy balance closed to the case's preset's :data:`ENERGY_TOLS` (``energy_residual``,
  when the installed library has the energy account; otherwise "energy balance: not
  available" is printed), unless :func:`cardiosoft.results.flags` says the beat carries no
  more energy than the account's round-off;
- the periodic steady state reached, or the member's message saying it is not (or that the
  solver failed); "ok" only when it is;
- every metric physical (:func:`physical_problems`: positive volumes, 0 <= EF <= 1, a cable
  force and mechanical work >= 0, an efficiency in [0, 1], ...) or flagged by
  :func:`cardiosoft.results.flags` with a reason that covers it (pressures outside the fitted
  range: extrapolated; a cable that would push), and the quasi-static stroke's pressure, head
  plus column rise, inside the fitted range or flagged.

A closed-loop member (:func:`check_loop_member`) gets the checks that apply to it (finite,
volume, steadiness said; none of the pump scenes' energy and physical bounds) and two more:

- a native side's pump fields (peak force, smallest cable force, cable work) are NaN by
  definition, not a failure (a finite one is);
- at the periodic steady state the left and right net outputs are equal to within what the
  beat's cycle change allows (``residual`` times :func:`left_half_capacity` over the period,
  plus :data:`BALANCE_QUADRATURE` for the trapezoid's means): mass balance of the left half.

Its flags (:func:`cardiosoft.network.loop_results.loop_flags`: congestion, a collapsing atrium,
blood
piled up on one side, a pump's pressure outside the fitted range or a cable that would push)
are notes: the case is flagged, not failed.

**The quick subset** (``--quick``, the CI's): one compiled solve per scene structure (the
static strokes, the bench, a Windkessel), the grid at 60 bpm (and 300 for the bench) with the
default preset, one stiff case each, sharp valves, both preloads, hypothesis draws of the static
scene's numbers and of the dynamic scenes' members (at the grid's rates: a member drawn from the
whole range, 1e-308 bpm up, can run 16384 steps a beat, minutes for its batch), the command
line on the static scene, and the closed loops in one batch per structure
(:func:`~cardiosoft.stress.loop_cases.quick_loop_batches`): ``heart`` at 60 and 180 bpm, and
``tah`` at 60 and 180 bpm as shipped and at 180 bpm at the extreme opposite corners (left
Omega 0, C 0.01 with right Omega 6, C 0.65, and the reverse). Longer runs are the full
suite's.

A case **passes** when every check holds and nothing is flagged; it is **flagged** when it holds
but the member is flagged, not steady (and says so) or its solver failed (and says so); it
**fails** otherwise. A failure matching :data:`KNOWN_FAILURES` is counted as **known**: printed
with its reason, not failing the run. The suite prints a progress line per batch and one table
(cases, passed, flagged, failed, known, time per group). Exit status: 1 when a case failed (a
``failed:`` line each on stderr); a known failure is a flag (a ``warning:`` line), which
``--strict`` turns into exit status 1; a flagged case is neither (the library flagged its own
numbers, as it should); 2 for bad input.

**Where it lives.** :mod:`~cardiosoft.stress.cases` (what is run),
:mod:`~cardiosoft.stress.loop_cases` (the closed loops'),
:mod:`~cardiosoft.stress.model_cases` (the pump in an svZeroDSolver model),
:mod:`~cardiosoft.stress.draws`
(hypothesis), :mod:`~cardiosoft.stress.checks` (what is checked, outcomes, known failures),
:mod:`~cardiosoft.stress.runner` (a batch through the API and the command line),
:mod:`~cardiosoft.stress.suite` (:func:`plan`, :func:`run_suite`),
:mod:`~cardiosoft.stress.report` and :mod:`~cardiosoft.stress.cli`.
"""

from cardiosoft.stress.cases import (
    GRID_AFTERLOADS_MMHG,
    GRID_BPMS,
    GRID_OMEGAS,
    GRID_SHORTENINGS,
    GROUPS,
    LONG_BEATS,
    PRELOADS_MMHG,
    SHARP_SMOOTHING_MMHG,
    VALVE_RESISTANCE_RANGE,
    WINDKESSEL_OPEN_AT_LO,
    WINDKESSEL_RANGES,
    Batch,
    Case,
    grid_batches,
    long_batches,
    preload_batches,
    shooting_batches,
    stiff_batches,
    valve_batches,
)
from cardiosoft.stress.checks import (
    BALANCE_QUADRATURE,
    ENERGY_TOLS,
    KNOWN_FAILURES,
    VOLUME_TOL,
    KnownFailure,
    LoopView,
    MemberView,
    Outcome,
    check_loop_member,
    check_member,
    left_half_capacity,
    physical_problems,
)
from cardiosoft.stress.cli import main
from cardiosoft.stress.draws import property_batches
from cardiosoft.stress.loop_cases import (
    LOOP_BPMS,
    LoopBatch,
    LoopCase,
    loop_batches,
    quick_loop_batches,
)
from cardiosoft.stress.model_cases import (
    BALANCE_TOL,
    MODEL_PLACES,
    ModelBatch,
    ModelCase,
    balance_allowance,
    check_model_member,
    model_batches,
)
from cardiosoft.stress.report import SuiteReport
from cardiosoft.stress.suite import plan, run_suite

__all__ = [
    "BALANCE_QUADRATURE",
    "BALANCE_TOL",
    "ENERGY_TOLS",
    "GRID_AFTERLOADS_MMHG",
    "GRID_BPMS",
    "GRID_OMEGAS",
    "GRID_SHORTENINGS",
    "GROUPS",
    "KNOWN_FAILURES",
    "LONG_BEATS",
    "LOOP_BPMS",
    "MODEL_PLACES",
    "PRELOADS_MMHG",
    "SHARP_SMOOTHING_MMHG",
    "VALVE_RESISTANCE_RANGE",
    "VOLUME_TOL",
    "WINDKESSEL_OPEN_AT_LO",
    "WINDKESSEL_RANGES",
    "Batch",
    "Case",
    "KnownFailure",
    "LoopBatch",
    "LoopCase",
    "LoopView",
    "MemberView",
    "ModelBatch",
    "ModelCase",
    "Outcome",
    "SuiteReport",
    "balance_allowance",
    "check_loop_member",
    "check_member",
    "check_model_member",
    "grid_batches",
    "left_half_capacity",
    "long_batches",
    "loop_batches",
    "main",
    "model_batches",
    "physical_problems",
    "plan",
    "preload_batches",
    "property_batches",
    "quick_loop_batches",
    "run_suite",
    "shooting_batches",
    "stiff_batches",
    "valve_batches",
]
