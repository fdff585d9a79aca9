"""``--uncertainty`` of the soft pump in a user's svZeroDSolver model: the pump's posterior
draws solved in one batched call, and every record's numbers' 95 % band over them."""

from __future__ import annotations

import numpy as np

from cardiosoft.network.pump_in_model import PumpPlacement, placed_records, with_pump_draws
from cardiosoft.network.run import simulate
from cardiosoft.posterior import band


def pump_bands(
    model, placement: PumpPlacement, posterior, steady: bool = False, accuracy: str = "default"
):
    """``--uncertainty`` with the pump placed: every draw of ``posterior`` (a
    :class:`~cardiosoft.pump.PosteriorDraws` of the placement's surrogate) solved in one
    batched call (:func:`~cardiosoft.network.pump_in_model.with_pump_draws`), and each
    record's numbers' 95 % band over the draws that solved (:func:`cardiosoft.posterior.band`;
    the pump's posterior alone, as a closed loop's band: no model discrepancy was measured in
    a circulation), at the solver preset ``accuracy`` and, with ``steady``, the periodic
    steady state. Returns ``({BLOCK: {KEY: Band}}, failed draws, draws)``."""
    variants = with_pump_draws(model, placement, posterior.pump)
    traces = simulate(model, accuracy, variants=variants, steady=steady)
    n = next(iter(traces.values.values())).shape[0]
    per_draw = []
    for i in range(n):
        one = traces.variant(i)
        with np.errstate(all="ignore"):
            per_draw.append(placed_records(model, placement, one))
    good = traces.solved and traces.steady is not False

    def numbers(rec):  # a pump that does no cable work has no efficiency (None): not a failure
        return [v for r in rec.values() for v in r.values() if v is not None]

    ok = [good and bool(np.all(np.isfinite(numbers(rec)))) for rec in per_draw]
    failed = n - sum(ok)
    bands = {}
    for block, record in per_draw[0].items():
        bands[block] = {}
        for key in record:
            values = [rec[block][key] for rec, k in zip(per_draw, ok, strict=True) if k]
            values = np.array([v for v in values if v is not None])
            bands[block][key] = band(values, values, failed)
    return bands, failed, n
