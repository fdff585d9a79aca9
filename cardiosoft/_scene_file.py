"""Reading a scene file: its numeric keys and its tables, every error naming file and key.

Shared by the pump scenes (:mod:`cardiosoft.scene`) and the closed-loop scenes
(:mod:`cardiosoft.network.loop_scene`).
"""

from __future__ import annotations

import dataclasses
import math


@dataclasses.dataclass(frozen=True)
class _Number:
    """One numeric key: where it lives in the file, its unit, its range, its Scene field."""

    field: str
    key: str  # "section.key" in the file
    unit: str
    lo: float
    hi: float
    lo_open: bool = False
    scale: float = 1.0  # SI value of one user unit
    default: float | None = None
    index: int | None = None  # position in a tuple field
    when: str = "always"  # "always", an afterload type, or "effect:NAME"

    def allowed(self) -> str:
        right = ")" if self.hi == math.inf else "]"
        return f"{'(' if self.lo_open else '['}{self.lo:g}, {self.hi:g}{right} {self.unit}".rstrip()


class _Reader:
    """Reads one table of a scene file, consuming keys and naming file and key in errors."""

    def __init__(self, source: str, table: dict, prefix: str = ""):
        self.source, self.table, self.prefix = source, dict(table), prefix
        self.known: list[str] = []  # keys asked for, listed when an unknown key is found

    def _where(self, key):
        return f"{self.source}: key '{self.prefix}{key}'"

    def pop(self, key, default=None):
        self.known.append(key)
        return self.table.pop(key, default)

    def sub(self, key, required: bool) -> _Reader | None:
        value = self.pop(key)
        if value is None:
            if required:
                raise ValueError(f"{self._where(key)} is missing (a table [{key}])")
            return None
        if not isinstance(value, dict):
            raise ValueError(f"{self._where(key)} = {value!r} must be a table [{key}]")
        return _Reader(self.source, value, f"{self.prefix}{key}.")

    def number(self, spec: _Number, key: str):
        """The value(s) in SI; ranges are checked later, by :func:`_validated`."""
        value = self.pop(key, spec.default)
        what = "a list of numbers" if spec.field == "afterloads" else "a number"
        if value is None:
            raise ValueError(f"{self._where(key)} is missing; allowed: {what} in {spec.allowed()}")
        values = value if spec.field == "afterloads" and isinstance(value, list) else [value]
        if (
            (spec.field == "afterloads" and not isinstance(value, list))
            or not values
            or any(isinstance(v, bool) or not isinstance(v, int | float) for v in values)
        ):
            raise ValueError(f"{self._where(key)} = {value!r}: allowed {what} in {spec.allowed()}")
        converted = tuple(float(v) * spec.scale for v in values)
        return converted if spec.field == "afterloads" else converted[0]

    def choice(self, key, choices, default=None):
        value = self.pop(key, default)
        if value not in choices:
            raise ValueError(f"{self._where(key)} = {value!r}: allowed {', '.join(choices)}")
        return value

    def text(self, key, default=""):
        value = self.pop(key, default)
        if not isinstance(value, str):
            raise ValueError(f"{self._where(key)} = {value!r}: allowed a string")
        return value

    def done(self):
        if self.table:
            key = sorted(self.table)[0]
            allowed = ", ".join(sorted(set(self.known))) or "none"
            raise ValueError(
                f"{self._where(key)} is not a known key (value {self.table[key]!r}); "
                f"allowed keys here: {allowed}"
            )
