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


def parse_values(value, name: str) -> tuple[float, ...]:
    """The values of one swept variable: ``"START:STOP:N"`` (N points from START to STOP, both
    included), one number, or a sequence of numbers. ``ValueError`` names ``name``."""
    if isinstance(value, str):
        parts = value.split(":")
        try:
            numbers = [float(p) for p in parts]
        except ValueError:
            numbers = None
        if numbers is None or len(parts) not in (1, 3):
            raise ValueError(
                f"{name} = {value!r}: allowed START:STOP:N (N points from START to STOP) or "
                "one number"
            )
        if len(parts) == 1:
            values = numbers
        else:
            start, stop, n = numbers
            if n != int(n) or n < 1:
                raise ValueError(f"{name} = {value!r}: N = {parts[2]} must be a whole number >= 1")
            if int(n) > 1 and start == stop:
                raise ValueError(
                    f"{name} = {value!r}: an empty range (START = STOP with N > 1 points)"
                )
            values = np.linspace(start, stop, int(n)).tolist()
    else:
        try:
            values = [float(v) for v in np.atleast_1d(np.asarray(value, dtype=float)).ravel()]
        except (TypeError, ValueError):
            raise ValueError(f"{name} = {value!r}: allowed numbers or START:STOP:N") from None
    if not values:
        raise ValueError(f"{name}: an empty range; give at least one value")
    if len(set(values)) != len(values):
        raise ValueError(f"{name} = {value!r}: the values repeat; give each value once")
    return tuple(values)
