"""Eager checks of physical parameters at the public edge.

Each check names the parameter, its value, its unit and the allowed range in one sentence, so
that a CLI can print the message as it is. Traced values (inside ``jit``/``vmap``/``grad``) are
not checked: they were checked where they entered, and Python control flow on them is
impossible anyway.
"""

import math

import jax
import numpy as np


def _is_traced(value) -> bool:
    return isinstance(value, jax.core.Tracer)


def _fmt(v: float) -> str:
    return f"{v:.6g}"


def check_range(
    name: str,
    value,
    unit: str,
    lo: float = -math.inf,
    hi: float = math.inf,
    *,
    lo_open: bool = False,
    hi_open: bool = False,
    scale: float = 1.0,
):
    """Raise ``ValueError`` unless every element of ``value / scale`` lies in the range.

    ``scale`` is the SI value of ``unit``: the message reports the value in the user's unit
    (``check_range("afterload", p, "mmHg", 0, 200, scale=mmHg)``).
    """
    if _is_traced(value):
        return value
    arr = np.asarray(value, dtype=float) / scale
    left = "(" if lo_open or math.isinf(lo) else "["
    right = ")" if hi_open or math.isinf(hi) else "]"
    allowed = f"{left}{_fmt(lo)}, {_fmt(hi)}{right}"
    unit_txt = f" {unit}" if unit and unit != "-" else " (dimensionless)"
    for v in np.atleast_1d(arr).ravel():
        bad = not math.isfinite(v)
        bad = bad or (v <= lo if lo_open else v < lo) or (v >= hi if hi_open else v > hi)
        if bad:
            raise ValueError(
                f"{name} = {_fmt(v)}{unit_txt} is outside the allowed range {allowed}{unit_txt}"
                if math.isfinite(v)
                else f"{name} = {v}{unit_txt} is not a finite number; allowed range {allowed}"
                f"{unit_txt}"
            )
    return value


def check_positive(name: str, value, unit: str, *, scale: float = 1.0):
    """``check_range`` for a strictly positive finite quantity."""
    return check_range(name, value, unit, 0.0, math.inf, lo_open=True, scale=scale)
