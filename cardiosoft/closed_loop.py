"""The closed circulation as one vector field: four chambers, four vessels, four valves.

The 12-state model of Regazzoni et al. 2022 (J. Comput. Phys. 457, 111083, section 2; the
notes' equations in ``notes/closed-loop-regazzoni.md``), in SI::

    V_LA' = Q_VEN_PUL - Q_MV        V_LV' = Q_MV - Q_AV
    V_RA' = Q_VEN_SYS - Q_TV        V_RV' = Q_TV - Q_PV
    C_AR_SYS p_AR_SYS' = Q_AV - Q_AR_SYS          L_AR_SYS Q_AR_SYS' = p_AR_SYS - p_VEN_SYS - R Q
    C_VEN_SYS p_VEN_SYS' = Q_AR_SYS - Q_VEN_SYS   L_VEN_SYS Q_VEN_SYS' = p_VEN_SYS - p_RA - R Q
    C_AR_PUL p_AR_PUL' = Q_PV - Q_AR_PUL          L_AR_PUL Q_AR_PUL' = p_AR_PUL - p_VEN_PUL - R Q
    C_VEN_PUL p_VEN_PUL' = Q_AR_PUL - Q_VEN_PUL   L_VEN_PUL Q_VEN_PUL' = p_VEN_PUL - p_LA - R Q

with the valve flows ``Q = valve(p_up - p_down)``: mitral LA -> LV, aortic LV -> AR_SYS,
tricuspid RA -> RV, pulmonary RV -> AR_PUL. Each chamber is an
:class:`~cardiosoft.heart.ElastanceChamber` or the soft pump, a
:class:`~cardiosoft.heart.PumpChamber`: a pump in place of a ventricle keeps the rest of the
loop (filled from its atrium through the inlet valve, ejecting through the outlet valve into
the same arterial compartment).

State (a dict, SI)::

    {"la": {"volume"}, "lv": {"volume"}, "ra": {"volume"}, "rv": {"volume"},
     "ar_sys": {"pressure", "flow"}, "ven_sys": ..., "ar_pul": ..., "ven_pul": ...}

Blood volume is conserved: the chambers' volumes plus ``C p`` of each vessel
(:meth:`ClosedLoop.total_volume`).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from cardiosoft.heart import AbstractChamber, PumpChamber, Vessel
from cardiosoft.valves import ArctanValve, Valve

__all__ = ["CHAMBERS", "VALVES", "VESSELS", "ClosedLoop"]

CHAMBERS = ("la", "lv", "ra", "rv")
"""Left atrium, left ventricle, right atrium, right ventricle."""
VESSELS = ("ar_sys", "ven_sys", "ar_pul", "ven_pul")
"""Systemic arteries, systemic veins, pulmonary arteries, pulmonary veins."""
VALVES = {
    "mitral": ("la", "lv"),
    "aortic": ("lv", "ar_sys"),
    "tricuspid": ("ra", "rv"),
    "pulmonary": ("rv", "ar_pul"),
}
"""Each valve's upstream and downstream compartment."""
_VESSEL_PATH = {  # each vessel: (the valve or vessel that fills it, the compartment it drains to)
    "ar_sys": ("aortic", "ven_sys"),
    "ven_sys": ("ar_sys", "ra"),
    "ar_pul": ("pulmonary", "ven_pul"),
    "ven_pul": ("ar_pul", "la"),
}
_CHAMBER_PATH = {  # each chamber: (what fills it, the valve it empties through)
    "la": ("ven_pul", "mitral"),
    "lv": ("mitral", "aortic"),
    "ra": ("ven_sys", "tricuspid"),
    "rv": ("tricuspid", "pulmonary"),
}


class ClosedLoop(eqx.Module):
    """The closed circulation's vector field (module docstring).

    **Arguments:** the chambers ``la``, ``lv``, ``ra``, ``rv``
    (:class:`~cardiosoft.heart.AbstractChamber`: elastance chambers or pumps, one period for
    all); the vessels ``ar_sys``, ``ven_sys``, ``ar_pul``, ``ven_pul``
    (:class:`~cardiosoft.heart.Vessel`); the valves ``mitral``, ``aortic``, ``tricuspid``,
    ``pulmonary`` (:class:`~cardiosoft.valves.ArctanValve` or
    :class:`~cardiosoft.valves.Valve`).
    """

    la: AbstractChamber
    lv: AbstractChamber
    ra: AbstractChamber
    rv: AbstractChamber
    ar_sys: Vessel
    ven_sys: Vessel
    ar_pul: Vessel
    ven_pul: Vessel
    mitral: ArctanValve | Valve
    aortic: ArctanValve | Valve
    tricuspid: ArctanValve | Valve
    pulmonary: ArctanValve | Valve

    def __check_init__(self):
        periods = [getattr(self, c).period for c in CHAMBERS]
        if not any(isinstance(p, jax.core.Tracer) for p in periods):
            values = np.asarray(periods, dtype=float)
            if not np.allclose(values, values[0], rtol=1e-12, atol=0.0):
                raise ValueError(
                    f"chamber periods = {', '.join(f'{v:g}' for v in values)} s: the four "
                    "chambers of a closed loop beat at one rate"
                )

    @property
    def period(self) -> jax.Array:
        """The beat period T (s)."""
        return self.lv.period

    @property
    def pumps(self) -> tuple[str, ...]:
        """The chambers that are soft pumps (static)."""
        return tuple(c for c in CHAMBERS if isinstance(getattr(self, c), PumpChamber))

    def init(self) -> dict:
        """The state at t = 0: the native chambers' and vessels' initial values; a pump filled
        at its filling chamber's pressure at t = 0 (its atrium's), at its pull at t = 0."""
        y = {v: getattr(self, v).init() for v in VESSELS}
        for c in ("la", "ra", "lv", "rv"):  # the atria first: they fill the ventricles
            chamber = getattr(self, c)
            upstream = {"lv": "la", "rv": "ra"}.get(c)
            fill = 0.0 if upstream is None else self._pressure(upstream, 0.0, y)
            y[c] = {"volume": chamber.start_volume(fill)}
        return {k: y[k] for k in (*CHAMBERS, *VESSELS)}

    def _pressure(self, name, t, y) -> jax.Array:
        if name in VESSELS:
            return y[name]["pressure"]
        return getattr(self, name).pressure(t, y[name]["volume"])

    def _flows(self, t, y) -> tuple[dict, dict]:
        """(pressures, valve flows) at time t (SI)."""
        pressures = {name: self._pressure(name, t, y) for name in (*CHAMBERS, *VESSELS)}
        flows = {
            valve: getattr(self, valve).flow(pressures[up] - pressures[down])
            for valve, (up, down) in VALVES.items()
        }
        return pressures, flows

    def __call__(self, t, y, args=None) -> dict:
        pressures, flows = self._flows(t, y)
        flows |= {v: y[v]["flow"] for v in VESSELS}
        dy = {
            c: {"volume": flows[fill] - flows[empty]} for c, (fill, empty) in _CHAMBER_PATH.items()
        }
        for v, (fill, drain) in _VESSEL_PATH.items():
            dy[v] = getattr(self, v).rhs(y[v], flows[fill], pressures[drain])
        return {k: dy[k] for k in (*CHAMBERS, *VESSELS)}

    def signals(self, t, y) -> dict:
        """Everything observable at time t (SI), by name: ``{c}_pressure`` and ``{c}_volume``
        of every chamber and vessel (a vessel's volume is ``C p``), ``{v}_flow`` through every
        valve and vessel, and for each pump ``{c}_pull`` (m) and ``{c}_cable_force`` (N)."""
        pressures, flows = self._flows(t, y)
        out = {f"{k}_pressure": p for k, p in pressures.items()}
        out |= {f"{c}_volume": y[c]["volume"] for c in CHAMBERS}
        out |= {f"{v}_volume": getattr(self, v).volume(y[v]) for v in VESSELS}
        out |= {f"{k}_flow": q for k, q in flows.items()}
        out |= {f"{v}_flow": y[v]["flow"] for v in VESSELS}
        for c in self.pumps:
            chamber = getattr(self, c)
            out |= {f"{c}_{k}": s for k, s in chamber.observe(t, y[c]["volume"]).items()}
        return out

    def total_volume(self, y) -> jax.Array:
        """Blood volume (m^3): the chambers' volumes plus ``C p`` of each vessel; conserved."""
        chambers = sum(y[c]["volume"] for c in CHAMBERS)
        return chambers + sum(getattr(self, v).volume(y[v]) for v in VESSELS)

    def kink_times(self) -> jax.Array:
        """Kinks of the forcing within one beat (s), sorted, from 0 to the period: every
        chamber's activation or pull phase boundaries (pass as ``jump_ts``)."""
        phases = [getattr(self, c).kink_phases() for c in CHAMBERS]
        ends = jnp.asarray([0.0, 1.0], dtype=jnp.result_type(float))
        return jnp.sort(jnp.concatenate([ends, *phases])) * self.period
