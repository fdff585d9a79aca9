"""svZeroDSolver's ``simulation_parameters``: what a run of a read model does
(``src/solve/SimulationParameters.cpp`` and ``src/solve/Solver.cpp`` of
``SimVascular/svZeroDSolver``), and the error every refusal of the reader raises.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

UNSUPPORTED_OPTIONS = ("coupled_simulation",)
"""svZeroDSolver simulation options the reader refuses when they are switched on."""


class UnsupportedModel(ValueError):
    """A model the reader cannot take, or that svZeroDSolver itself would refuse."""


@dataclass(frozen=True)
class Simulation:
    """svZeroDSolver's ``simulation_parameters`` that the run uses."""

    cycles: int
    points_per_cycle: int
    steady_initial: bool = True
    output_all_cycles: bool = False
    cycle_error: float | None = None
    """``use_cycle_to_cycle_error``'s bound (``sim_cycle_to_cycle_percent_error`` / 100) or None:
    with an RCR, ``cycles`` is svZeroDSolver's count from the largest Rd C (Pfaller et al. 2021,
    eq. 21); else the run goes on a beat at a time until the mean flow and pressure at every
    node of ``caps`` (``UP:DOWN``: each vessel's inlet boundary, else its outlet's) change by at
    most this much a beat (:func:`cardiosoft.network.run.simulate`)."""
    caps: tuple[str, ...] = ()
    mean_only: bool = False
    """``output_mean_only``: the output is each variable's mean over the output samples (both
    ends of a beat included, every beat's with ``output_all_cycles``), as svZeroDSolver's
    ``csv_writer`` averages them; the records still describe the last beat."""
    derivative: bool = False
    """``output_derivative``: the output has each variable's time derivative too (``ydot``)."""
    rho_infty: float = 0.5
    """``rho_infty``: the spectral radius at infinity of svZeroDSolver's generalized-alpha
    scheme, used where a model is stepped as svZeroDSolver steps it
    (:mod:`cardiosoft.network.gen_alpha`)."""

    @property
    def steps_per_cycle(self) -> int:
        return self.points_per_cycle - 1


def read_simulation(sim: dict, config: dict, period: float) -> Simulation:
    """The run settings of the model ``config`` (its ``simulation_parameters`` ``sim``, its
    period in its units of time); an option this reader does not take is refused."""
    return _cycle_rule(_parameters(sim), config, period)


def _parameters(sim: dict) -> Simulation:
    for option in UNSUPPORTED_OPTIONS:
        if sim.get(option):
            raise UnsupportedModel(f"simulation option {option!r} is not supported")
    if sim.get("output_interval", 1) != 1:
        raise UnsupportedModel("simulation option 'output_interval' other than 1 is not supported")
    cycles, error = int(sim["number_of_cardiac_cycles"]), None
    if sim.get("use_cycle_to_cycle_error"):
        if cycles < 2:  # svZeroDSolver asserts two beats to compare
            raise UnsupportedModel(f"use_cycle_to_cycle_error needs 2 cycles or more, not {cycles}")
        error = float(sim.get("sim_cycle_to_cycle_percent_error", 1.0)) / 100.0
    return Simulation(
        cycles=cycles,
        points_per_cycle=int(sim["number_of_time_pts_per_cardiac_cycle"]),
        steady_initial=bool(sim.get("steady_initial", True)),
        output_all_cycles=bool(sim.get("output_all_cycles", False)),
        cycle_error=error,
        mean_only=bool(sim.get("output_mean_only", False)),
        derivative=bool(sim.get("output_derivative", False)),
        rho_infty=float(sim.get("rho_infty", 0.5)),
    )


def _cycle_rule(simulation: Simulation, config: dict, period: float) -> Simulation:
    """``use_cycle_to_cycle_error`` as svZeroDSolver applies it (:attr:`Simulation.cycle_error`)."""
    if simulation.cycle_error is None:
        return simulation
    taus = [
        float(bc["bc_values"]["Rd"]) * float(bc["bc_values"]["C"])
        for bc in config["boundary_conditions"]
        if bc["bc_type"] == "RCR"
    ]
    if taus:
        cycles = math.ceil(-max(taus) / period * math.log(simulation.cycle_error))
        return dataclasses.replace(simulation, cycles=cycles)
    caps = [  # svZeroDSolver's get_vessel_caps_dof_indices
        f"{e['inlet']}:{v['vessel_name']}" if "inlet" in e else f"{v['vessel_name']}:{e['outlet']}"
        for v in config.get("vessels", [])
        if (e := v.get("boundary_conditions", {}))
    ]
    return dataclasses.replace(simulation, caps=tuple(caps))
