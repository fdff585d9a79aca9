"""Time integration: the only module of cardiosoft that calls ``diffrax.diffeqsolve``.

Solver settings are data (:class:`SolverConfig`); :func:`preset` gives the named ones. Solves
never throw (``throw=False``): callers inspect ``sol.result`` (and mask it under ``vmap``).
Beat after beat to the periodic steady state: :mod:`cardiosoft.periodic`.

Choosing (``notes/diffrax-practice.md``): Tsit5 for the smooth bench; ``preset(..., stiff=True)``
(Kvaerno5 with a Newton root finder and PID (0.3, 0.4)) when valves or tiny inertances make the
model stiff; compare ``sol.stats["num_steps"]`` before deciding. ``atol`` is absolute in SI and
shared by every state component: pressures (Pa, ~1e4) and volumes (m^3, ~1e-5) differ by nine
orders of magnitude, so for volumes ``atol`` rather than ``rtol`` usually sets the accuracy.

diffrax (and optimistix, lineax) are imported where a solve is traced, not with this module: a
command whose programs come from the program store (:mod:`cardiosoft.program_store`) never
traces one, and spares their import (0.4-0.5 s of a fresh process, issue #41). So the presets
name their solver and adjoint (:class:`SolverConfig`), and a solve's result leaves a program as
diffrax's integer code (:func:`result_code`), not as diffrax's enumeration.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from cardiosoft.circulation import inlet_pressure

if TYPE_CHECKING:
    import diffrax

__all__ = [
    "ACCURACY_PRESETS",
    "PRESETS",
    "SUCCESSFUL",
    "TIGHTER",
    "SolverConfig",
    "describe",
    "diffrax_objects",
    "integrate",
    "preset",
    "ran_out_of_steps",
    "rerun_settings",
    "respond",
    "result_code",
    "result_code_of",
    "result_message",
    "solver_name",
]


class SolverConfig(eqx.Module):
    """Solver settings.

    **Arguments:**

    - ``solver`` (static): a diffrax solver instance, or the name of one built when a solve is
      traced: ``"Tsit5"`` (the default), ``"Kvaerno5"`` (with a Newton root finder at the
      controller's tolerances), or any other diffrax solver that takes no arguments.
    - ``rtol``, ``atol``: tolerances of the PID controller (atol in SI units of the state).
    - ``pcoeff``, ``icoeff``: PID coefficients; (0, 1) is the plain I controller.
    - ``max_steps`` (static): bound on the number of steps (sizes the checkpoint memory).
    - ``dt0``: first step (s); None picks it automatically.
    - ``fixed_steps`` (static): None for error control (the PID controller), or a number of
      equal steps over the solve's interval, without error control (still cut at ``jump_ts``).
      For checking derivatives against finite differences: with equal steps the discretisation
      is the same on both sides of the difference, so the two agree to the difference's own
      truncation error.
    - ``adjoint`` (static): diffrax adjoint, an instance or a name as ``solver``; the default
      ``"RecursiveCheckpointAdjoint"`` for reverse mode, ``"ForwardMode"`` for
      ``jax.jvp``/``jacfwd`` (least-squares fitting).
    """

    solver: Any = eqx.field(static=True, default="Tsit5")
    rtol: jax.Array = eqx.field(converter=jnp.asarray, default=1e-6)
    atol: jax.Array = eqx.field(converter=jnp.asarray, default=1e-9)
    pcoeff: jax.Array = eqx.field(converter=jnp.asarray, default=0.0)
    icoeff: jax.Array = eqx.field(converter=jnp.asarray, default=1.0)
    max_steps: int = eqx.field(static=True, default=16384)
    dt0: float | None = None
    fixed_steps: int | None = eqx.field(static=True, default=None)
    adjoint: Any = eqx.field(static=True, default="RecursiveCheckpointAdjoint")


def diffrax_objects(config: SolverConfig) -> tuple:
    """``config``'s solver and adjoint as diffrax's objects, those given by name built."""
    import diffrax

    def built(field, value, kind):
        if not isinstance(value, str):
            return value
        if value == "Kvaerno5":  # the stiff preset's: Newton at the controller's tolerances
            import optimistix as optx

            newton = diffrax.with_stepsize_controller_tols(optx.Newton)()
            return diffrax.Kvaerno5(root_finder=newton)
        found = getattr(diffrax, value, None)
        if not (isinstance(found, type) and issubclass(found, kind)):
            raise ValueError(
                f"SolverConfig {field} = {value!r}: not the name of a diffrax {kind.__name__} "
                "(e.g. 'Tsit5', 'Kvaerno5'; adjoints 'RecursiveCheckpointAdjoint', 'ForwardMode')"
            )
        return found()

    return (
        built("solver", config.solver, diffrax.AbstractSolver),
        built("adjoint", config.adjoint, diffrax.AbstractAdjoint),
    )


def solver_name(config: SolverConfig) -> str:
    """The name of ``config``'s solver (``"Tsit5"``, ``"Kvaerno5"``, ...)."""
    solver = config.solver
    return solver if isinstance(solver, str) else type(solver).__name__


SUCCESSFUL = 0
"""diffrax's result code of a solve that succeeded (``RESULTS.successful``)."""


def result_code(result) -> jax.Array:
    """diffrax's result (an item of its ``RESULTS`` enumeration, or already its code) as its
    integer code: the enumeration's one array leaf."""
    (code,) = jax.tree_util.tree_leaves(result)
    return code


def result_code_of(name: str) -> int:
    """The code of diffrax's result ``name`` (``"max_steps_reached"``, ...)."""
    import diffrax

    return int(result_code(getattr(diffrax.RESULTS, name)))


def ran_out_of_steps(codes) -> np.ndarray:
    """Per member of result ``codes`` (concrete): the solver reached ``max_steps``. diffrax is
    imported only when some member did not succeed."""
    codes = np.asarray(codes)
    if np.all(codes == SUCCESSFUL):
        return np.zeros(codes.shape, dtype=bool)
    return codes == result_code_of("max_steps_reached")


def result_message(code) -> str:
    """diffrax's message for the result ``code`` (a scalar)."""
    import diffrax

    successful = diffrax.RESULTS.successful
    code = jnp.asarray(code, result_code(successful).dtype)
    item = jax.tree_util.tree_unflatten(jax.tree_util.tree_structure(successful), [code])
    return str(diffrax.RESULTS[item]).strip()


PRESETS: dict[str, dict] = {
    "fast": dict(rtol=1e-4, atol=1e-8),
    "default": dict(rtol=1e-6, atol=1e-9),
    "reference": dict(rtol=1e-10, atol=1e-13, max_steps=65536),
}
"""Named non-stiff configurations, as :class:`SolverConfig` arguments with the ``Tsit5`` solver;
:func:`preset` builds them (plain numbers here: no JAX array is built at import time, so float64
can be switched on after ``import cardiosoft``).

"reference" uses Tsit5, not Dopri8: output at ``ts`` is interpolated, and diffrax's Dopri8
interpolant was measured 300x less accurate there (relative error 8e-9 against 3e-11 for Tsit5
on an RC decay at rtol 1e-10), although Dopri8 is more accurate at its own steps.
"""

ACCURACY_PRESETS: tuple[str, ...] = tuple(PRESETS)
"""The names of the presets, ``("fast", "default", "reference")``: the accuracy a scene asks for."""


TIGHTER = 100.0
"""A run at ``"reference"`` already is verified at ``rtol`` and ``atol`` this many times tighter
(:func:`cardiosoft.verify_run`)."""


def describe(config: SolverConfig) -> str:
    """A configuration in words: solver, rtol, atol."""
    return f"{solver_name(config)}, rtol {float(config.rtol):.0e}, atol {float(config.atol):.0e}"


def rerun_settings(accuracy: str, run: SolverConfig, reference: SolverConfig) -> tuple[str, str]:
    """A run at preset ``accuracy`` (its configuration ``run``) and its verifying rerun at
    ``reference``, in words (:func:`cardiosoft.verify_run`'s ``run_setting`` and
    ``reference_setting``)."""
    which = "preset 'reference'" if accuracy != "reference" else f"{TIGHTER:g}x tighter"
    return f"preset {accuracy!r}: {describe(run)}", f"{which}: {describe(reference)}"


def preset(name: str, stiff: bool = False) -> SolverConfig:
    """The named configuration (``"fast"``, ``"default"``, ``"reference"``), built anew.

    With ``stiff=True`` the solver is ``Kvaerno5`` with a Newton root finder at the controller's
    tolerances and the PID coefficients are (0.3, 0.4).
    """
    if name not in PRESETS:
        raise ValueError(f"solver preset {name!r} is not one of {', '.join(PRESETS)}")
    if stiff:
        return SolverConfig("Kvaerno5", pcoeff=0.3, icoeff=0.4, **PRESETS[name])
    return SolverConfig("Tsit5", **PRESETS[name])


def integrate(
    vector_field,
    y0,
    t0,
    t1,
    *,
    args=None,
    ts=None,
    jump_ts=None,
    config=None,
    dense=False,
    max_step=None,
) -> diffrax.Solution:
    """Solve ``dy/dt = vector_field(t, y, args)`` from ``t0`` to ``t1``.

    **Arguments:**

    - ``vector_field``: ``(t, y, args) -> dy/dt`` with the pytree structure of ``y0``. Pass
      parameters through ``args`` (or make it a Module), not by closure, to avoid recompiles.
    - ``y0``: any pytree of arrays (e.g. a dict of scalars).
    - ``ts``: save times (interpolated); None saves ``t1`` only.
    - ``jump_ts``: known kinks/jumps of the forcing in time (e.g. ``CablePull.kink_times``),
      stepped to exactly through ``ClipStepSizeController``.
    - ``config``: a :class:`SolverConfig`, ``preset("default")`` when None.
    - ``dense``: keep the dense interpolant (``sol.evaluate``).
    - ``max_step``: the longest step (same unit as t), None for no cap. Error control cannot
      see forcing that falls entirely between two steps: cap the step below the shortest
      feature of a forcing whose kinks are not passed as ``jump_ts``.

    **Returns:** the ``diffrax.Solution``; never throws, check ``sol.result``.
    """
    import diffrax

    config = preset("default") if config is None else config
    solver, adjoint = diffrax_objects(config)
    dt0 = config.dt0
    if config.fixed_steps is None:
        controller = diffrax.PIDController(
            rtol=config.rtol,
            atol=config.atol,
            pcoeff=config.pcoeff,
            icoeff=config.icoeff,
            dtmax=max_step,
        )
    else:
        # equal steps that may still be cut at jump_ts (ClipStepSizeController needs an adaptive
        # controller): tolerances no error can reach, every step as long as dtmax allows
        dt0 = (jnp.asarray(t1) - jnp.asarray(t0)) / config.fixed_steps
        controller = diffrax.PIDController(rtol=1e30, atol=1e30, dtmax=dt0)
    if jump_ts is not None:
        controller = diffrax.ClipStepSizeController(controller, jump_ts=jump_ts)
    ftype = jnp.result_type(float)
    saveat = (
        diffrax.SaveAt(t1=True, dense=dense)
        if ts is None
        else diffrax.SaveAt(ts=jnp.asarray(ts, dtype=ftype), dense=dense)
    )
    return diffrax.diffeqsolve(
        diffrax.ODETerm(vector_field),
        solver,
        jnp.asarray(t0, dtype=ftype),
        jnp.asarray(t1, dtype=ftype),
        dt0,
        y0,
        args=args,
        saveat=saveat,
        stepsize_controller=controller,
        adjoint=adjoint,
        max_steps=config.max_steps,
        throw=False,
    )


def _afterload_field(t, y, args):
    block, inflow = args
    return block.node_rhs(y, inflow(t))


@eqx.filter_jit
def _respond(block, inflow, ts, y0, config, jump_ts, max_step):
    sol = integrate(
        _afterload_field,
        y0,
        0.0,
        ts[-1],
        args=(block, inflow),
        ts=ts,
        jump_ts=jump_ts,
        config=config,
        max_step=max_step,
    )

    def pressure(t, y):
        q, dqdt = jax.jvp(inflow, (t,), (jnp.ones_like(t),))
        return inlet_pressure(block, y, q, dqdt)

    return jax.vmap(pressure)(ts, sol.ys), sol.result, sol.stats["num_steps"]


def respond(
    block, inflow, ts, y0=None, config=None, *, jump_ts=None, max_step="auto"
) -> jax.Array:
    """Inlet pressure (Pa) of an afterload driven standalone by a prescribed inflow.

    **Arguments:**

    - ``block``: an :class:`~cardiosoft.circulation.AbstractAfterload`.
    - ``inflow``: a JAX function ``q(t)`` (m^3/s); dq/dt comes from ``jax.jvp``. Make it an
      ``eqx.Module`` with array fields (or a module-level function) so that a new inflow
      does not recompile.
    - ``ts``: increasing output times (s), ``ts[-1] > 0``; the solve runs from t = 0.
    - ``y0``: initial block state; ``block.init()`` (rest) when None.
    - ``config``: a :class:`SolverConfig` (``preset("default")`` when None); ``jump_ts``:
      kinks of ``inflow`` (s).
    - ``max_step``: the longest solver step (s). ``"auto"`` (the default): the shortest
      interval of ``ts`` without ``jump_ts``, no cap with them. Error control only sees the
      inflow where it steps: a pulse that falls between two steps would vanish without a word,
      so without the kinks the step is kept as fine as the output grid (a pulse the grid
      resolves is resolved). ``None``: no cap.

    **Returns:** the inlet pressure at ``ts``. Raises ``RuntimeError`` if the solve failed, or
    an equinox runtime error when called under ``jit``.
    """
    ts = jnp.asarray(ts, dtype=jnp.result_type(float))
    y0 = block.init() if y0 is None else y0
    config = preset("default") if config is None else config
    if isinstance(max_step, str):
        if max_step != "auto":
            raise ValueError(f"max_step = {max_step!r}: allowed 'auto', None or a step in s")
        gaps = jnp.diff(jnp.concatenate([jnp.zeros(1, ts.dtype), ts]))
        max_step = None if jump_ts is not None else jnp.min(jnp.where(gaps > 0, gaps, jnp.inf))
    p, result, num_steps = _respond(block, inflow, ts, y0, config, jump_ts, max_step)
    failed = result_code(result) != SUCCESSFUL
    message = "respond: the afterload solve failed; raise max_steps or loosen the tolerances"
    if isinstance(failed, jax.core.Tracer):
        return eqx.error_if(p, failed, message)
    if bool(failed):
        reason = result_message(result_code(result))
        raise RuntimeError(f"{message}: {reason} ({int(num_steps)} steps taken)")
    return p
