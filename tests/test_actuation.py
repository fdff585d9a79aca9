"""Tests of cardiosoft.actuation against hand-computed values (derivations: tests/README.md)."""

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cardiosoft.actuation import SHAPES, CablePull
from cardiosoft.solve import integrate
from cardiosoft.units import minute, mm

STROKE = 50 * mm  # the paper's bench: 3000 mm/min for 1 s


@pytest.mark.parametrize("shape", SHAPES)
def test_ends_of_phases(shape):
    pull = CablePull(STROKE, 2.0, 0.3, 0.1, 0.4, shape=shape)
    # phase ends: pull 0.6 s, hold until 0.8 s, release until 1.6 s, rest until 2 s
    x = jax.vmap(pull)(jnp.array([0.0, 0.6, 0.7, 0.8, 1.6, 1.8, 2.0]))
    np.testing.assert_allclose(x, [0, STROKE, STROKE, STROKE, 0, 0, 0], rtol=0, atol=1e-15)
    # half-way through the pull every profile is symmetric: x = stroke / 2
    np.testing.assert_allclose(pull(0.3), STROKE / 2, rtol=1e-14)


@pytest.mark.parametrize("shape", SHAPES)
def test_periodic(shape):
    pull = CablePull.from_bpm(STROKE, 72.0, shape=shape)
    ts = jnp.linspace(0.0, 60 / 72, 37)
    for k in (1, 3, -2):
        np.testing.assert_allclose(
            jax.vmap(pull)(ts + k * 60 / 72), jax.vmap(pull)(ts), rtol=0, atol=1e-12 * STROKE
        )


def test_paper_speed_linear():
    # 30 bpm, pull and release in 1 s each: 3000 mm/min, as on the paper's bench
    pull = CablePull.from_bpm(STROKE, 30.0)
    ts = jnp.array([0.1, 0.5, 0.93, 2.2])  # inside pull phases
    np.testing.assert_allclose(jax.vmap(pull.velocity)(ts), 3000 * mm / minute, rtol=1e-13)
    np.testing.assert_allclose(pull.velocity(1.5), -3000 * mm / minute, rtol=1e-13)
    # stroke / (pull_fraction * period), with a shorter pull
    fast = CablePull(STROKE, 2.0, pull_fraction=0.25, release_fraction=0.5)
    np.testing.assert_allclose(fast.velocity(0.2), STROKE / 0.5, rtol=1e-13)
    np.testing.assert_allclose(fast.velocity(1.0), -STROKE / 1.0, rtol=1e-13)
    np.testing.assert_allclose(fast.velocity(1.8), 0.0, atol=0)  # rest


@pytest.mark.parametrize(("shape", "peak"), [("smoothstep", 1.5), ("cosine", np.pi / 2)])
def test_smooth_shapes_peak_speed(shape, peak):
    # peak of f'(s) at s = 1/2: 6 s (1 - s) = 3/2; (pi/2) sin(pi s) = pi/2
    pull = CablePull(STROKE, 2.0, shape=shape)
    np.testing.assert_allclose(pull.velocity(0.5), peak * STROKE / 1.0, rtol=1e-13)
    np.testing.assert_allclose(pull.velocity(1.5), -peak * STROKE / 1.0, rtol=1e-13)
    np.testing.assert_allclose(pull.velocity(1e-9), 0.0, atol=1e-8 * STROKE)  # C1 start


@pytest.mark.parametrize("shape", SHAPES)
def test_velocity_matches_finite_difference(shape):
    pull = CablePull(STROKE, 1.7, 0.35, 0.05, 0.3, shape=shape)
    ts = jnp.array([0.05, 0.2, 0.5, 0.7, 0.99, 1.5, 1.9])  # away from the kinks
    h = 1e-6
    fd = (jax.vmap(pull)(ts + h) - jax.vmap(pull)(ts - h)) / (2 * h)
    np.testing.assert_allclose(jax.vmap(pull.velocity)(ts), fd, rtol=1e-6, atol=1e-9)


def test_kink_times():
    pull = CablePull(STROKE, 2.0, 0.3, 0.1, 0.4)
    expected = [0.0, 0.6, 0.8, 1.6, 2.0, 2.6, 2.8, 3.6, 4.0]
    np.testing.assert_allclose(pull.kink_times(2), expected, rtol=1e-15)
    with pytest.raises(ValueError, match="n_beats"):
        pull.kink_times(0)


def test_integrating_velocity_with_kinks_reproduces_pull():
    pull = CablePull(STROKE, 1.0, 0.3, 0.1, 0.4)
    ts = jnp.linspace(0.0, 3.0, 61)
    sol = integrate(
        lambda t, y, args: args.velocity(t),
        jnp.zeros(()),
        0.0,
        3.0,
        args=pull,
        ts=ts,
        jump_ts=pull.kink_times(3),
    )
    assert sol.result == diffrax.RESULTS.successful
    # default tolerances (atol 1e-9 m); without jump_ts the error here is about 7e-6 m
    np.testing.assert_allclose(sol.ys, jax.vmap(pull)(ts), rtol=0, atol=1e-8)


def test_vmap_over_rates():
    x = jax.vmap(lambda b: CablePull.from_bpm(STROKE, b)(0.25))(jnp.array([30.0, 60.0]))
    # 30 bpm: pull over 1 s -> x = stroke / 4; 60 bpm: pull over 0.5 s -> stroke / 2
    np.testing.assert_allclose(x, [STROKE / 4, STROKE / 2], rtol=1e-14)


def test_new_period_does_not_recompile():
    @eqx.filter_jit
    @eqx.debug.assert_max_traces(max_traces=1)
    def position(pull, t):
        return pull(t)

    a = position(CablePull.from_bpm(STROKE, 30.0), jnp.asarray(0.25))
    b = position(CablePull.from_bpm(STROKE, 60.0), jnp.asarray(0.25))
    c = position(CablePull(2 * STROKE, 3.0, 0.2, 0.2, 0.2), jnp.asarray(0.25))
    np.testing.assert_allclose([a, b, c], [STROKE / 4, STROKE / 2, 2 * STROKE * 0.25 / 0.6])


@pytest.mark.parametrize(
    ("make", "words"),
    [
        (lambda: CablePull.from_bpm(STROKE, -30.0), ["beat rate = -30 bpm", "(0, 300] bpm"]),
        (lambda: CablePull.from_bpm(STROKE, 400.0), ["beat rate = 400 bpm", "(0, 300] bpm"]),
        (lambda: CablePull(-5 * mm, 2.0), ["cable stroke = -5 mm", "(0, inf"]),
        (lambda: CablePull(STROKE, 0.0), ["period = 0 s", "(0, inf"]),
        (lambda: CablePull(STROKE, 2.0, pull_fraction=0.0), ["pull fraction = 0", "(0, 1]"]),
        (lambda: CablePull(STROKE, 2.0, release_fraction=0.0), ["release fraction = 0"]),
        (lambda: CablePull(STROKE, 2.0, hold_fraction=-0.1), ["hold fraction = -0.1", "[0, 1]"]),
        (lambda: CablePull(STROKE, 2.0, 0.6, 0.1, 0.4), ["pull + hold + release", "= 1.1"]),
        (
            lambda: CablePull(STROKE, 2.0, shape="square"),
            ["'square'", "linear, smoothstep, cosine"],
        ),
    ],
)
def test_validation_messages(make, words):
    with pytest.raises(ValueError) as info:
        make()
    for word in words:
        assert word in str(info.value)


def test_fractions_summing_to_one_with_round_off_are_accepted():
    pull = CablePull(STROKE, 1.0, 0.1, 0.2, 0.7)  # 0.1 + 0.2 + 0.7 = 1.0000000000000002
    np.testing.assert_allclose(pull(0.999), STROKE * (1 - 0.699 / 0.7), rtol=1e-10)


# ------------------------------------------------------- the drive's jerk-limited ends (#39)
def test_zero_ramp_is_the_ideal_triangle_exactly():
    ts = jnp.linspace(0.0, 4.0, 801)
    ideal = CablePull(46e-3, 2.0)
    ramped = CablePull(46e-3, 2.0, ramp_time=0.0)
    np.testing.assert_array_equal(np.asarray(ideal(ts)), np.asarray(ramped(ts)))


def test_ramped_pull_keeps_stroke_and_phases_and_limits_acceleration():
    """Closed forms of the raised-cosine speed ramp (module docstring): the stroke is reached
    at the phase's end; the cruise speed is v / (1 - r) with v the triangle's; the speed is
    continuous (C1 pull) and the largest acceleration is pi v_c / (2 t_r), by finite
    differences of the pull."""
    stroke, period, ramp = 46e-3, 2.0, 0.1
    pull = CablePull(stroke, period, ramp_time=ramp)
    t_phase = 0.5 * period
    v = stroke / t_phase
    cruise = v / (1.0 - ramp / t_phase)
    assert float(pull(t_phase)) == pytest.approx(stroke, rel=1e-14)
    assert float(pull(0.5 * t_phase)) == pytest.approx(0.5 * stroke, rel=1e-12)
    assert float(pull.velocity(0.5 * t_phase)) == pytest.approx(cruise, rel=1e-12)
    ts = np.linspace(0.0, period, 200_001)
    x = np.asarray(pull(jnp.asarray(ts)))
    dt = ts[1] - ts[0]
    speed = np.gradient(x, dt)
    assert np.max(np.abs(np.diff(speed))) < 1e-3 * cruise  # no jump: C1
    accel = np.gradient(speed, dt)
    assert np.max(np.abs(accel)) == pytest.approx(np.pi * cruise / (2 * ramp), rel=1e-3)
    assert abs(float(pull.velocity(0.0))) < 1e-12  # starts from rest


def test_ramp_is_refused_where_it_does_not_apply():
    with pytest.raises(ValueError, match=r"ramp time = 0\.1 s: allowed only with the linear"):
        CablePull(46e-3, 2.0, shape="cosine", ramp_time=0.1)
    with pytest.raises(ValueError, match="ramp time"):
        CablePull(46e-3, 2.0, ramp_time=0.6)  # more than half the 1-s pull
    with pytest.raises(ValueError, match="ramp time"):
        CablePull(46e-3, 2.0, ramp_time=-0.01)
