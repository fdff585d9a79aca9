"""Displacement-controlled cable pull x(t) (paper section II-F; DESIGN.md section 3.4).

The bench pulls the disk holding the cables by a ``stroke`` and releases it, at about
3000 mm/min: pull and release in 2 s, i.e. a triangle wave at 30 bpm. One period ``T`` is split
into four phases, as fractions of ``T``:

``pull`` (x rises 0 -> stroke), ``hold`` (dwell at full pull), ``release`` (stroke -> 0), and the
rest of the period at x = 0. Within the pull and release phases the profile follows ``shape``:

- ``"linear"``: constant speed (the paper's triangle, or a trapezoid with a dwell);
- ``"smoothstep"``: ``3 s^2 - 2 s^3`` (zero speed at the phase ends, C1);
- ``"cosine"``: the raised cosine ``(1 - cos(pi s)) / 2`` (zero speed at the phase ends, C1).

A real drive cannot start and stop at full speed: a universal testing machine's crosshead
accelerates over a finite time. ``ramp_time`` (s, ``"linear"`` only; 0 by default, the ideal
triangle) gives each phase of the linear shape jerk-limited ends: over the ramp the speed rises
as a raised cosine from 0 to the cruise speed ``v_c = v / (1 - r)`` (r the ramp's fraction of
the phase, ``v`` the triangle's speed), so stroke and phase durations are unchanged, the speed
is C1 and the acceleration, at most ``pi v_c / (2 t_r)``, is continuous.

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


def _profile(shape: str, s, ramp=0.0):
    """Normalised rise f(s) on s in [0, 1], f(0) = 0, f(1) = 1; ``ramp`` (linear only): the
    fraction of the phase, in [0, 1/2], over which a jerk-limited end accelerates."""
    if shape == "linear":
        return _ramped_linear(s, ramp)
    if shape == "smoothstep":
        return s * s * (3.0 - 2.0 * s)
    return 0.5 * (1.0 - jnp.cos(jnp.pi * s))


def _ramped_linear(s, r):
    """Constant cruise speed ``v_c = 1 / (1 - r)`` with raised-cosine speed ramps of length r
    at both ends (module docstring); exactly ``s`` at ``r = 0``."""
    cruise = 1.0 / (1.0 - r)
    safe_r = jnp.where(r > 0.0, r, 1.0)

    def ramp_distance(u):  # distance covered u into a ramp from rest: int_0^u v(u') du'
        return 0.5 * cruise * (u - safe_r / jnp.pi * jnp.sin(jnp.pi * u / safe_r))

    middle = cruise * (s - 0.5 * r)
    return jnp.where(
        s < r, ramp_distance(s), jnp.where(s > 1.0 - r, 1.0 - ramp_distance(1.0 - s), middle)
    )


class CablePull(eqx.Module):
    """Periodic cable pull x(t) in m.

    **Arguments:**

    - ``stroke``: full pull (m), > 0. The paper's prototype: C L(Omega) = 0.4 L(4).
    - ``period``: beat period T (s), > 0. The paper: 2 s (30 bpm). See :meth:`from_bpm`.
    - ``pull_fraction``: duration of the pull as a fraction of T, in (0, 1]; default 0.5.
    - ``hold_fraction``: dwell at full pull, in [0, 1]; default 0.
    - ``release_fraction``: duration of the release, in (0, 1]; default 0.5.
      ``pull + hold + release <= 1``; the rest of the period is rest at x = 0.
    - ``ramp_time``: the jerk-limited ends of a ``"linear"`` phase (s), >= 0 and at most half
      the shortest phase; default 0 (start and stop at full speed).
    - ``shape`` (static): one of :data:`SHAPES`, default ``"linear"``.
    """

    stroke: jax.Array = eqx.field(converter=jnp.asarray)
    period: jax.Array = eqx.field(converter=jnp.asarray)
    pull_fraction: jax.Array = eqx.field(converter=jnp.asarray, default=0.5)
    hold_fraction: jax.Array = eqx.field(converter=jnp.asarray, default=0.0)
    release_fraction: jax.Array = eqx.field(converter=jnp.asarray, default=0.5)
    ramp_time: jax.Array = eqx.field(converter=jnp.asarray, default=0.0)
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
        if not _is_traced(self.ramp_time):
            check_range("ramp time", self.ramp_time, "s", 0.0, float("inf"))
            if self.shape != "linear" and float(jnp.max(self.ramp_time)) > 0.0:
                raise ValueError(
                    f"ramp time = {float(jnp.max(self.ramp_time)):g} s: allowed only with the "
                    f"linear shape (the {self.shape} shape already starts and stops at rest)"
                )
            if not any(_is_traced(v) for v in (self.period, *fractions)):
                t_pull, _, t_release = self._durations
                check_range(
                    "ramp time",
                    self.ramp_time,
                    "s",
                    0.0,
                    float(0.5 * jnp.minimum(t_pull, t_release).min()),
                )

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
        rise = _profile(self.shape, s_pull, self.ramp_time / t_pull)
        fall = _profile(self.shape, s_release, self.ramp_time / t_release)
        return self.stroke * (rise - fall)

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
