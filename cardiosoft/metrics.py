"""Beat metrics from the traces of a periodic steady state (DESIGN.md section 3.5).

All quantities are SI. The paper's definitions (section II-F): stroke volume SV as the volume
ejected into the afterload (for the bench, the peak rise of the column); hydraulic work
``H = P_a SV``; mechanical work ``M`` the integral of the measured cable force over the cable
displacement during the pull; efficiency ``e = H / M``.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp

__all__ = ["BeatMetrics", "beat_metrics", "field_at", "trapezoid"]


def trapezoid(y, x):
    """Trapezoidal integral of samples ``y`` over ``x`` (last axis)."""
    return jnp.sum(0.5 * (y[..., 1:] + y[..., :-1]) * jnp.diff(x, axis=-1), axis=-1)


class BeatMetrics(eqx.Module):
    """Metrics of one beat (SI)."""

    edv: jax.Array
    """End-diastolic (largest) pump volume (m^3)."""
    esv: jax.Array
    """End-systolic (smallest) pump volume (m^3)."""
    stroke_volume: jax.Array
    """EDV - ESV (m^3): for the bench the column's peak rise, the paper's dynamic SV."""
    ejected_volume: jax.Array
    """The pump's own ejection (m^3): its volume when the pull begins less its smallest. Below
    ``stroke_volume`` where the line's fluid still flows in after the pull has begun (the
    column sloshing): the column's rise then counts that inflow too
    (:func:`cardiosoft.results.flags`)."""
    ejection_fraction: jax.Array
    """SV / EDV, from the pump's own volumes: at most 1 whenever ESV >= 0
    (:func:`cardiosoft.results.flags` reports it as none where ESV < 0)."""
    cardiac_output: jax.Array
    """SV / period (m^3/s)."""
    peak_force: jax.Array
    """Largest measured cable force during the pull (N)."""
    mech_work: jax.Array
    """Integral of the measured cable force over the pull, the paper's M (J)."""
    reference_pressure: jax.Array
    """P_a: the column head before the pull, or the afterload pressure's mean over time (Pa)."""
    hydraulic_work_paper: jax.Array
    """P_a SV, the paper's hydraulic work (J)."""
    hydraulic_work_pull: jax.Array
    """Integral of P_pump dV_out during the pull: the work the pump really did (J)."""
    stroke_work: jax.Array
    """Area of the pressure-volume loop, -(closed integral of P_pump dV) (J)."""
    efficiency: jax.Array
    """P_a SV / M, the paper's efficiency."""
    min_pump_pressure: jax.Array
    """Smallest chamber pressure of the beat's samples (Pa); with the largest, whether the
    surrogate was used inside the pressure range it was fitted on."""
    max_pump_pressure: jax.Array
    """Largest chamber pressure of the beat's samples (Pa)."""
    min_cable_force: jax.Array
    """Smallest measured cable force of the beat's samples (N): negative means the prescribed
    pull needs a cable that pushes."""
    # The energy account of the beat (J), with PumpCircuit(energy=True); None without it.
    work_in: jax.Array | None = None
    """Work of the cables plus that of the filling source over the beat (J)."""
    work_delivered: jax.Array | None = None
    """Work done on the fluid past the outlet: the afterload's, its line included (J)."""
    work_lost: jax.Array | None = None
    """Lost to cable friction, the shell's viscosity and the valves (J)."""
    stored_change: jax.Array | None = None
    """Change of the shell's strain energy over the beat (J); 0 at the periodic steady state."""
    stored_energy: jax.Array | None = None
    """The shell's strain energy at the beat's start (J): the scale of the round-off of
    ``stored_change`` (:func:`cardiosoft.results.flags`)."""
    energy_residual: jax.Array | None = None
    """|work_in - work_delivered - work_lost - stored_change| over the energy the beat carries,
    (|work_in| + |work_delivered| + |work_lost| + |stored_change|) / 2: how well the account
    closes (the solver's error; ~tolerance). The scale is the work in at a periodic beat that
    delivers and loses energy; it also counts energy that the afterload gives back (delivered
    < 0) and that the shell stores (a beat that is not periodic), and the residual is at most 2."""
    energy_efficiency: jax.Array | None = None
    """work_delivered / work_in: in [0, 1] at a periodic beat whenever the losses are >= 0, at
    any rate and afterload (:func:`cardiosoft.results.flags` says where it is not meaningful)."""


def beat_metrics(
    ts, volume, signals, n_pull: int, period, reference_pressure, energy=None
) -> BeatMetrics:
    """Metrics from the last beat's samples.

    ``ts`` (s), ``volume`` (m^3) and the ``signals`` of :meth:`PumpCircuit.signals` are sampled
    over one period; the first ``n_pull`` samples (static) span exactly the pull phase.
    ``energy``: the beat's energy account, ``(terms, stored_change, stored_energy)`` with
    ``terms`` the accumulated :meth:`PumpCircuit.power` terms over the beat, ``stored_change``
    the change of the shell's strain energy over it and ``stored_energy`` that energy at its
    start (J), or None.
    """
    edv, esv = jnp.max(volume), jnp.min(volume)
    sv = edv - esv
    force, pull = signals["cable_force"][:n_pull], signals["pull"][:n_pull]
    mech = trapezoid(force, pull)
    p_pump, q_out = signals["pump_pressure"], signals["outflow"]
    hyd_pull = trapezoid(p_pump[:n_pull] * q_out[:n_pull], ts[:n_pull])
    stroke_work = -trapezoid(p_pump, volume)
    h_paper = reference_pressure * sv
    return BeatMetrics(
        edv=edv,
        esv=esv,
        stroke_volume=sv,
        ejected_volume=volume[0] - esv,  # sample 0 is the pull's start
        ejection_fraction=sv / edv,
        cardiac_output=sv / period,
        # the largest sample picked by index, not jnp.max: measured, the tangent of jnp.max
        # inside the beat loop came out 0 under a vmap of jacfwd (the index's does not)
        peak_force=force[jnp.argmax(force)],
        mech_work=mech,
        reference_pressure=reference_pressure,
        hydraulic_work_paper=h_paper,
        hydraulic_work_pull=hyd_pull,
        stroke_work=stroke_work,
        efficiency=h_paper / mech,
        min_pump_pressure=jnp.min(p_pump),
        max_pump_pressure=jnp.max(p_pump),
        min_cable_force=jnp.min(signals["cable_force"]),
        **({} if energy is None else _energy_account(*energy)),
    )


def _energy_account(terms: dict, stored_change, stored_energy) -> dict:
    zero = jnp.zeros_like(terms["cable_in"])
    work_in = terms["cable_in"] + terms.get("atrium_in", zero)
    lost = sum((terms.get(k, zero) for k in ("friction", "viscous", "valves")), zero)
    delivered = terms["delivered"]
    closure = work_in - delivered - lost - stored_change
    # the energy the beat carries: each side of the balance, in = delivered + lost + stored
    carried = 0.5 * (jnp.abs(work_in) + jnp.abs(delivered) + jnp.abs(lost) + jnp.abs(stored_change))
    return {
        "work_in": work_in,
        "work_delivered": delivered,
        "work_lost": lost,
        "stored_change": stored_change,
        "stored_energy": stored_energy,
        "energy_residual": jnp.abs(closure) / carried,
        "energy_efficiency": delivered / work_in,
    }


def field_at(metrics, path: str):
    """The field at a dotted ``path`` of a metrics module (``"stroke_volume"``, a closed loop's
    ``"left.stroke_volume"``)."""
    for name in path.split("."):
        metrics = getattr(metrics, name)
    return metrics
