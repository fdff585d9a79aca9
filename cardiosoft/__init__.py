"""cardiosoft: a differentiable lumped-parameter model of a cable-driven soft pump used as an
artificial heart ventricle (after "Harnessing Mechanical Instabilities in the Development of an
Efficient Soft Pump for an Artificial Heart Ventricle Simulator").

SI units inside (m, m^3, Pa, N, s); see :mod:`cardiosoft.units` for conversions. float64 is
recommended (switch on JAX's 64-bit mode in your script, as the README shows) and is what the
CLIs, notebooks and tests use; the library never switches it on by itself, and no module builds
a JAX array when it is imported, so the switch may come after ``import cardiosoft``.

The public names below are imported on first use (PEP 562), so ``import cardiosoft`` costs
no JAX import (about 1.5 s): ``cardiosoft --help`` and a script that uses one module pay only
for what they import (issue #41). The command-line modules (``python -m
cardiosoft.simulate``, ``python -m cardiosoft.geometry``) are never imported here, so that
running one does not find it imported already.
"""

__version__ = "0.1.0"

from typing import TYPE_CHECKING

from cardiosoft.lazy import on_first_use

# --- the public API: each name and the module that defines it, imported on first use --------
PUBLIC = {
    "BeatSolution": "cardiosoft.batch",
    "StaticSolution": "cardiosoft.batch",
    "scene_circuit": "cardiosoft.batch",
    "solve_orbit": "cardiosoft.batch",
    "solve_static": "cardiosoft.batch",
    "run": "cardiosoft.experiment",
    "run_designs": "cardiosoft.experiment",
    "Shell": "cardiosoft.geometry",
    "apex_motion": "cardiosoft.geometry",
    "cavity_volume": "cardiosoft.geometry",
    "PumpSurrogate": "cardiosoft.pump",
    "load_pump": "cardiosoft.pump",  # pump.load
    "RunResult": "cardiosoft.results",
    "load_scene": "cardiosoft.scene",
    "solve_beats": "cardiosoft.scene_tools",
    "summary_records": "cardiosoft.scene_tools",
    "SolverConfig": "cardiosoft.solve",
    "preset": "cardiosoft.solve",
    "design_sweep": "cardiosoft.sweep",
    "Verification": "cardiosoft.verify",
    "verify_run": "cardiosoft.verify",
}
"""Each public name and the module it is defined in."""
RENAMED = {"load_pump": "load"}
"""Public names spelled otherwise in their module."""

__all__ = [
    "BeatSolution", "PumpSurrogate", "RunResult", "Shell", "SolverConfig", "StaticSolution",
    "Verification", "apex_motion", "cavity_volume", "design_sweep", "load_pump", "load_scene",
    "preset", "run", "run_designs", "scene_circuit", "solve_beats", "solve_orbit",
    "solve_static", "summary_records", "units", "verify_run",
]  # fmt: skip

if TYPE_CHECKING:  # what type checkers and IDEs read; at run time __getattr__ imports these
    from cardiosoft import units as units
    from cardiosoft.batch import BeatSolution as BeatSolution
    from cardiosoft.batch import StaticSolution as StaticSolution
    from cardiosoft.batch import scene_circuit as scene_circuit
    from cardiosoft.batch import solve_orbit as solve_orbit
    from cardiosoft.batch import solve_static as solve_static
    from cardiosoft.experiment import run as run
    from cardiosoft.experiment import run_designs as run_designs
    from cardiosoft.geometry import Shell as Shell
    from cardiosoft.geometry import apex_motion as apex_motion
    from cardiosoft.geometry import cavity_volume as cavity_volume
    from cardiosoft.pump import PumpSurrogate as PumpSurrogate
    from cardiosoft.pump import load as load_pump
    from cardiosoft.results import RunResult as RunResult
    from cardiosoft.scene import load_scene as load_scene
    from cardiosoft.scene_tools import solve_beats as solve_beats
    from cardiosoft.scene_tools import summary_records as summary_records
    from cardiosoft.solve import SolverConfig as SolverConfig
    from cardiosoft.solve import preset as preset
    from cardiosoft.sweep import design_sweep as design_sweep
    from cardiosoft.verify import Verification as Verification
    from cardiosoft.verify import verify_run as verify_run

__getattr__, __dir__ = on_first_use(globals(), PUBLIC, RENAMED)
