"""Displacement-controlled cable pull x(t) (paper section II-F; DESIGN.md section 3.4).

The bench pulls the disk holding the cables by a ``stroke`` and releases it, at about
3000 mm/min: pull and release in 2 s, i.e. a triangle wave at 30 bpm. One period ``T`` is split
into four phases, as fractions of ``T``:

``pull`` (x rises 0 -> stroke), ``hold`` (dwell at full pull), ``release`` (stroke -> 0), and the
rest of the period at x = 0. Within the pull and release phases the profile follows ``shape``:

- ``"linear"``: constant speed (the paper's triangle, or a trapezoid with a dwell);
- ``"smoothstep"``: ``3 s^2 - 2 s^3`` (zero speed at the phase ends, C1);
- ``"cosine"``: the raised cosine ``(1 - cos(pi s)) / 2`` (zero speed at the phase ends, C1).

All parameters are array leaves: a new stroke, period or fraction reuses the compiled code. The
phase boundaries are kinks (speed jumps for ``"linear"``, acceleration jumps otherwise); pass
:meth:`CablePull.kink_times` as ``jump_ts`` to the solver.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp

from cardiosoft._validate import _is_traced, check_positive, check_range
from cardiosoft.units import mm

__all__ = ["BPM_RANGE", "SHAPES", "CablePull"]

SHAPES = ("linear", "smoothstep", "cosine")
"""The allowed values of :attr:`CablePull.shape`."""
BPM_RANGE = (0.0, 300.0)
"""Allowed beat rate (bpm), open at 0: (0, 300]."""


def _profile(shape: str, s):
    """Normalised rise f(s) on s in [0, 1], f(0) = 0, f(1) = 1."""
    if shape == "linear":
        return s
    if shape == "smoothstep":
        return s * s * (3.0 - 2.0 * s)
    return 0.5 * (1.0 - jnp.cos(jnp.pi * s))


class CablePull(eqx.Module):
    """Periodic cable pull x(t) in m.

    **Arguments:**

    - ``stroke``: full pull (m), > 0. The paper's prototype: C L(Omega) = 0.4 L(4).
    - ``period``: beat period T (s), > 0. The paper: 2 s (30 bpm). See :meth:`from_bpm`.
    - ``pull_fraction``: duration of the pull as a fraction of T, in (0, 1]; default 0.5.
    - ``hold_fraction``: dwell at full pull, in [0, 1]; default 0.
    - ``release_fraction``: duration of the release, in (0, 1]; default 0.5.
      ``pull + hold + release <= 1``; the rest of the period is rest at x = 0.
    - ``shape`` (static): one of :data:`SHAPES`, default ``"linear"``.
    """

    stroke: jax.Array = eqx.field(converter=jnp.asarray)
    period: jax.Array = eqx.field(converter=jnp.asarray)
    pull_fraction: jax.Array = eqx.field(converter=jnp.asarray, default=0.5)
    hold_fraction: jax.Array = eqx.field(converter=jnp.asarray, default=0.0)
    release_fraction: jax.Array = eqx.field(converter=jnp.asarray, default=0.5)
    shape: str = eqx.field(static=True, default="linear")

    def __check_init__(self):
        if self.shape not in SHAPES:
            raise ValueError(f"shape = {self.shape!r} is not one of {', '.join(SHAPES)}")
        check_positive("cable stroke", self.stroke, "mm", scale=mm)
        check_positive("period", self.period, "s")
        check_range("pull fraction", self.pull_fraction, "-", 0.0, 1.0, lo_open=True)
        check_range("hold fraction", self.hold_fraction, "-", 0.0, 1.0)
        check_range("release fraction", self.release_fraction, "-", 0.0, 1.0, lo_open=True)
        fractions = (self.pull_fraction, self.hold_fraction, self.release_fraction)
        if not any(_is_traced(f) for f in fractions):
            total = self.pull_fraction + self.hold_fraction + self.release_fraction
            if float(jnp.max(total)) > 1.0 + 1e-12:  # round-off of e.g. 0.1 + 0.2 + 0.7
                check_range("pull + hold + release fractions", total, "-", 0.0, 1.0)

    @classmethod
    def from_bpm(cls, stroke, bpm, **kwargs) -> CablePull:
        """Build from a rate in beats per minute (:data:`BPM_RANGE`): ``period = 60 / bpm`` s."""
        check_range("beat rate", bpm, "bpm", *BPM_RANGE, lo_open=True)
        return cls(stroke, 60.0 / jnp.asarray(bpm), **kwargs)

    @property
    def _durations(self):
        T = self.period
        return self.pull_fraction * T, self.hold_fraction * T, self.release_fraction * T

    def __call__(self, t) -> jax.Array:
        """Cable pull x(t) (m), periodic with period T; x(0) = 0."""
        t_pull, t_hold, t_release = self._durations
        tau = jnp.mod(t, self.period)
        s_pull = jnp.clip(tau / t_pull, 0.0, 1.0)
        s_release = jnp.clip((tau - t_pull - t_hold) / t_release, 0.0, 1.0)
        return self.stroke * (_profile(self.shape, s_pull) - _profile(self.shape, s_release))

    def velocity(self, t) -> jax.Array:
        """Pull speed dx/dt (m/s) by forward-mode differentiation of :meth:`__call__`.

        At a kink it returns one of the one-sided values (or their mean): avoid sampling there.
        """
        t = jnp.asarray(t, dtype=jnp.result_type(float))
        return jax.jvp(self.__call__, (t,), (jnp.ones_like(t),))[1]

    def kink_times(self, n_beats: int) -> jax.Array:
        """Phase-boundary times over ``n_beats`` beats from t = 0 (s), sorted, shape
        ``(4 n_beats + 1,)``: for each beat its start, end of pull, end of hold, end of release,
        then ``n_beats T``. Coincident times (no hold, no rest) are kept: harmless as ``jump_ts``.
        """
        if not isinstance(n_beats, int) or n_beats < 1:
            raise ValueError(f"n_beats = {n_beats!r} must be a positive Python int")
        t_pull, t_hold, t_release = self._durations
        zero = jnp.zeros_like(t_pull)
        within = jnp.stack([zero, t_pull, t_pull + t_hold, t_pull + t_hold + t_release])
        starts = jnp.arange(n_beats)[:, None] * self.period
        return jnp.append((starts + within).ravel(), n_beats * self.period)

    @property
    def mean_speed(self) -> jax.Array:
        """Speed of the ``"linear"`` pull, stroke / (pull_fraction T) (m/s)."""
        return self.stroke / (self.pull_fraction * self.period)
