"""Tests of cardiosoft.circulation and cardiosoft.solve against closed-form solutions.

The derivations of the closed forms are in tests/README.md; they are evaluated here with numpy,
independently of the library's code.
"""

import itertools
import math

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
import pytest

from cardiosoft.circulation import (
    AtrialCompliance,
    AtrialSource,
    Bench,
    Tube,
    WaterColumn,
    Windkessel2,
    Windkessel3,
    Windkessel4,
    inlet_pressure,
)
from cardiosoft.solve import PRESETS, diffrax_objects, integrate, preset, respond
from cardiosoft.units import RHO_WATER, G, ml, mm, mmHg
from cardiosoft.valves import Valve

R_UNIT = mmHg / ml  # 1 mmHg s/ml in SI
C_UNIT = ml / mmHg  # 1 ml/mmHg in SI
REF = preset("reference")
# Tolerances: against a closed form the 'reference' preset (Tsit5, rtol 1e-10) is held to 1e-9,
# its global error over a few hundred steps (measured below 1e-10 here); a solution that is a
# polynomial of degree <= 4 in t (constant or ramped inflow) is integrated exactly by Tsit5
# (order 5), so only round-off is left (1e-12); algebra (a line's terms) to round-off, 1e-13.


# -- prescribed inflows: Modules with array fields, so that new values do not recompile --------


class Affine(eqx.Module):
    """q = q0 + a t (m^3/s)."""

    q0: jax.Array = eqx.field(converter=jnp.asarray)
    a: jax.Array = eqx.field(converter=jnp.asarray, default=0.0)

    def __call__(self, t):
        return self.q0 + self.a * t


class HalfSine(eqx.Module):
    """q = Q0 sin(pi tau / Ts) for tau = t mod T < Ts, else 0."""

    Q0: jax.Array = eqx.field(converter=jnp.asarray)
    Ts: jax.Array = eqx.field(converter=jnp.asarray)
    T: jax.Array = eqx.field(converter=jnp.asarray)

    def __call__(self, t):
        tau = jnp.mod(t, self.T)
        return jnp.where(tau < self.Ts, self.Q0 * jnp.sin(jnp.pi * tau / self.Ts), 0.0)

    def kinks(self, n: int):
        beats = jnp.arange(n) * self.T
        return jnp.sort(jnp.concatenate([beats, beats + self.Ts, (n * self.T)[None]]))


T_BEAT, T_EJECT = 0.8, 0.3
Q0 = 70 * ml * math.pi / (2 * T_EJECT)  # stroke volume 2 Q0 Ts / pi = 70 ml
EJECTION = HalfSine(Q0, T_EJECT, T_BEAT)


# -- numpy closed forms (tests/README.md) -------------------------------------------------------


def half_sine_periodic_pc(t, C, Rd, p_venous, Q0=Q0, Ts=T_EJECT, T=T_BEAT):
    """Periodic steady state of C dpc/dt = q - (pc - p_venous) / Rd under the half-sine."""
    tau_rc = Rd * C
    w = math.pi / Ts
    D = 1 / tau_rc**2 + w**2
    A = Q0 * w / (C * D)
    p0 = A * (math.exp(-(T - Ts) / tau_rc) + math.exp(-T / tau_rc)) / (1 - math.exp(-T / tau_rc))
    s = np.mod(t, T)
    ejecting = s < Ts
    during = p0 * np.exp(-s / tau_rc) + (Q0 / (C * D)) * (
        np.sin(w * s) / tau_rc - w * np.cos(w * s) + w * np.exp(-s / tau_rc)
    )
    p_end = p0 * math.exp(-Ts / tau_rc) + A * (1 + math.exp(-Ts / tau_rc))
    after = p_end * np.exp(-(s - Ts) / tau_rc)
    return p_venous + np.where(ejecting, during, after), p_venous + p0


def half_sine_q_dq(t, Q0=Q0, Ts=T_EJECT, T=T_BEAT):
    s = np.mod(t, T)
    w = math.pi / Ts
    on = s < Ts
    return np.where(on, Q0 * np.sin(w * s), 0.0), np.where(on, Q0 * w * np.cos(w * s), 0.0)


def half_sine_volume(t, Q0=Q0, Ts=T_EJECT, T=T_BEAT):
    """Integral of the half-sine inflow from 0 to t."""
    k, s = np.floor_divide(t, T), np.mod(t, T)
    per_beat = 2 * Q0 * Ts / math.pi
    within = np.where(s < Ts, Q0 * Ts / math.pi * (1 - np.cos(math.pi * s / Ts)), per_beat)
    return k * per_beat + within


# avoid sampling exactly at the kinks of the inflow
TS = np.linspace(0.013, 3 * T_BEAT - 0.011, 97)


# -- Windkessels ---------------------------------------------------------------------------------


def test_windkessel2_decay():
    wk = Windkessel2(R=1.1 * R_UNIT, C=1.3 * C_UNIT)
    P0 = 100 * mmHg
    y0 = wk.init() | {"pc": jnp.asarray(P0, dtype=float)}  # same dtypes as init()
    p = respond(wk, Affine(0.0), TS, y0=y0, config=REF)
    np.testing.assert_allclose(p, P0 * np.exp(-TS / (1.1 * 1.3)), rtol=1e-9)


@pytest.mark.parametrize("config", [REF, preset("default", stiff=True)], ids=["Tsit5", "Kvaerno5"])
def test_windkessel2_step_response(config):
    R, C, Q = 1.1 * R_UNIT, 1.3 * C_UNIT, 80 * ml
    p = respond(Windkessel2(R, C), Affine(Q), TS, config=config)
    rtol = 1e-9 if config is REF else 1e-5  # Kvaerno5 at 'default' (rtol 1e-6): 10x its rtol
    np.testing.assert_allclose(p, Q * R * (1 - np.exp(-TS / (R * C))), rtol=rtol)


def test_windkessel3_half_sine_periodic_state():
    @eqx.filter_jit
    @eqx.debug.assert_max_traces(max_traces=1)
    def simulate(wk, y0):
        return respond(wk, EJECTION, TS, y0=y0, config=REF, jump_ts=EJECTION.kinks(3))

    for wk in (Windkessel3.systemic(p_venous=5 * mmHg), Windkessel3.pulmonary(p_venous=0.0)):
        C, Rd, Rp, pv = (float(v) for v in (wk.C, wk.Rd, wk.Rp, wk.p_venous))
        pc, pc0 = half_sine_periodic_pc(TS, C, Rd, pv)
        q, _ = half_sine_q_dq(TS)
        p = simulate(wk, {"pc": jnp.asarray(pc0), "drained_volume": jnp.asarray(0.0)})
        np.testing.assert_allclose(p, Rp * q + pc, rtol=1e-9)


def test_windkessel4_inlet_pressure():
    wk = Windkessel4(0.05 * R_UNIT, 1.3 * C_UNIT, 1.05 * R_UNIT, 0.005 * mmHg / ml)
    pc, pc0 = half_sine_periodic_pc(TS, 1.3 * C_UNIT, 1.05 * R_UNIT, 0.0)
    q, dq = half_sine_q_dq(TS)
    y0 = {"pc": jnp.asarray(pc0), "drained_volume": jnp.asarray(0.0)}
    p = respond(wk, EJECTION, TS, y0=y0, config=REF, jump_ts=EJECTION.kinks(3))
    expected = 0.005 * mmHg / ml * dq + 0.05 * R_UNIT * q + pc
    np.testing.assert_allclose(p, expected, rtol=1e-9, atol=1e-9 * np.abs(expected).max())


def test_volume_bookkeeping():
    """Every stateful block under the same prescribed inflow, in one solve (one compile)."""
    blocks = {
        "wk3": Windkessel3.systemic(p_venous=4 * mmHg),
        "wk4": Windkessel4(0.05 * R_UNIT, 1.3 * C_UNIT, 1.05 * R_UNIT, 0.005 * mmHg / ml),
        "bench": Bench(Tube(0.5, 10 * mm), WaterColumn(30 * mm, 90 * mmHg)),
    }
    atrium = AtrialCompliance(C=2 * C_UNIT, p_venous=8 * mmHg, R_venous=0.02 * R_UNIT)

    def field(t, y, args):
        blocks, atrium = args
        q = EJECTION(t)
        rates = {k: b.node_rhs(y[k], q) for k, b in blocks.items()}
        rates["atrium"] = atrium.rhs(y["atrium"], q)  # the pump draws q out of the atrium
        return rates

    y0 = {k: b.init() for k, b in blocks.items()} | {"atrium": atrium.init()}
    ts = jnp.asarray(TS)
    sol = integrate(
        field, y0, 0.0, ts[-1], args=(blocks, atrium), ts=ts, jump_ts=EJECTION.kinks(3), config=REF
    )
    assert sol.result == diffrax.RESULTS.successful
    expected = half_sine_volume(TS)
    for k, b in blocks.items():
        stored = jax.vmap(b.stored_volume)(sol.ys[k]) - b.stored_volume(b.init())
        np.testing.assert_allclose(stored, expected, rtol=0, atol=1e-9 * expected.max(), err_msg=k)
    stored = jax.vmap(atrium.stored_volume)(sol.ys["atrium"])
    np.testing.assert_allclose(stored, -expected, rtol=0, atol=1e-9 * expected.max())
    assert float(sol.ys["atrium"]["pa"].min()) < 8 * mmHg  # drawing lowers the atrial pressure


def test_atrial_source():
    source = AtrialSource(pressure=10 * mmHg)
    y = source.init()
    assert float(source.pressure(y)) == 10 * mmHg
    assert float(source.rhs(y, 3 * ml)["supplied_volume"]) == 3 * ml
    assert float(source.stored_volume({"supplied_volume": jnp.asarray(3 * ml)})) == -3 * ml


# -- the bench --------------------------------------------------------------------------------


def test_water_column_constant_inflow():
    col = WaterColumn(40 * mm, 60 * mmHg)
    A = math.pi * 0.02**2
    h0 = 60 * mmHg / (RHO_WATER * G)
    Q = 100 * ml
    p = respond(col, Affine(Q), TS, config=REF)  # dq/dt = 0: no inertial term
    np.testing.assert_allclose(p, RHO_WATER * G * (h0 + Q * TS / A), rtol=1e-12)


def test_water_column_ramp_with_inertia():
    col = WaterColumn(40 * mm, 30 * mmHg)
    A = math.pi * 0.02**2
    h0 = 30 * mmHg / (RHO_WATER * G)
    a = 5e-5  # m^3/s^2
    h = h0 + a * TS**2 / 2 / A
    expected = RHO_WATER * h / A * a + RHO_WATER * G * h
    np.testing.assert_allclose(respond(col, Affine(0.0, a), TS, config=REF), expected, rtol=1e-11)


def test_water_column_without_rise():
    col = WaterColumn(40 * mm, 30 * mmHg, rise=False)
    A = math.pi * 0.02**2
    h0 = 30 * mmHg / (RHO_WATER * G)
    y = {"column_volume": jnp.asarray(50 * ml)}  # the level does not follow the volume
    np.testing.assert_allclose(col.node_pressure(y), 30 * mmHg, rtol=1e-14)
    np.testing.assert_allclose(
        inlet_pressure(col, y, 1e-4, 2e-3), 30 * mmHg + RHO_WATER * h0 / A * 2e-3, rtol=1e-14
    )
    np.testing.assert_allclose(col.node_rhs(y, 1e-4)["column_volume"], 1e-4, rtol=0)


def test_tube_coefficients():
    tube = Tube(length=1.0, diameter=10 * mm, loss_coefficient=0.8)
    d, mu, rho = 0.01, 1.0e-3, 998.0
    # alternative forms: 4 rho l / (pi d^2), 128 mu l / (pi d^4), 8 K rho / (pi^2 d^4)
    np.testing.assert_allclose(tube.line_inertance(), 4 * rho / (math.pi * d**2), rtol=1e-14)
    np.testing.assert_allclose(tube.line_resistance(), 128 * mu / (math.pi * d**4), rtol=1e-14)
    np.testing.assert_allclose(tube.line_loss(), 8 * 0.8 * rho / (math.pi**2 * d**4), rtol=1e-14)
    # in clinical units, by hand, to the 4 digits written (hence 1e-3): 0.0953 mmHg s^2/ml and
    # 0.0306 mmHg s/ml
    np.testing.assert_allclose(tube.line_inertance() / (mmHg / ml), 0.09531, rtol=1e-3)
    np.testing.assert_allclose(tube.line_resistance() / R_UNIT, 0.03056, rtol=1e-3)


def test_bench_sums_line_terms():
    bench = Bench(Tube(0.5, 12 * mm), WaterColumn(40 * mm, 90 * mmHg))
    V, q, dq = 30 * ml, 150 * ml, 2e-3
    At, Ac = math.pi * 0.006**2, math.pi * 0.02**2
    h = 90 * mmHg / (RHO_WATER * G) + V / Ac
    L = RHO_WATER * 0.5 / At + RHO_WATER * h / Ac
    R = 8 * 1e-3 * 0.5 / (math.pi * 0.006**4)
    K = RHO_WATER / (2 * At**2)
    expected = L * dq + R * q + K * q * q + RHO_WATER * G * h
    y = {"column_volume": jnp.asarray(V)}
    np.testing.assert_allclose(inlet_pressure(bench, y, q, dq), expected, rtol=1e-13)
    # reverse flow: the quadratic loss changes sign with q
    expected_back = L * dq - R * q - K * q * q + RHO_WATER * G * h
    np.testing.assert_allclose(inlet_pressure(bench, y, -q, dq), expected_back, rtol=1e-13)


# -- absent effects are absent -----------------------------------------------------------------


def _unused_inputs(fn, *args):
    jaxpr = jax.make_jaxpr(fn)(*args).jaxpr
    used = {id(v) for eqn in jaxpr.eqns for v in eqn.invars}
    used |= {id(v) for v in jaxpr.outvars}
    return [i for i, v in enumerate(jaxpr.invars) if id(v) not in used]


def test_absent_effects_are_none_and_untraced():
    y = {"column_volume": jnp.asarray(1e-5)}
    assert WaterColumn(30 * mm, 0.0, inertia=False).line_inertance(y) is None
    assert Tube(1.0, 10 * mm, inertia=False).line_inertance() is None
    assert Tube(1.0, 10 * mm, resistance=False).line_resistance() is None
    assert Tube(1.0, 10 * mm, minor_loss=False).line_loss() is None
    bare = Bench(
        Tube(1.0, 10 * mm, inertia=False, resistance=False, minor_loss=False),
        WaterColumn(30 * mm, 0.0, inertia=False),
    )
    assert bare.line_inertance(y) is None and bare.line_resistance(y) is None
    assert bare.line_loss(y) is None
    wk2, wk3 = Windkessel2(), Windkessel3()
    yw = wk2.init()
    assert wk2.line_inertance(yw) is None and wk2.line_resistance(yw) is None
    assert wk3.line_inertance(yw) is None and wk3.line_loss(yw) is None

    def pressure(col):
        return lambda v, q, dq: inlet_pressure(col, {"column_volume": v}, q, dq)

    args = (1e-5, 1e-4, 1e-3)
    # no rise, no inertia, no line terms: the inlet pressure depends on none of v, q, dq/dt
    assert _unused_inputs(
        pressure(WaterColumn(30 * mm, 1.0, rise=False, inertia=False)), *args
    ) == [0, 1, 2]
    # rise only: v is used; inertia only: dq/dt is used
    assert _unused_inputs(pressure(WaterColumn(30 * mm, 1.0, inertia=False)), *args) == [1, 2]
    assert _unused_inputs(pressure(WaterColumn(30 * mm, 1.0, rise=False)), *args) == [0, 1]
    with pytest.raises(ValueError, match="dqdt"):
        inlet_pressure(WaterColumn(30 * mm, 1.0), {"column_volume": 0.0}, 1e-4)


def test_new_parameters_do_not_recompile():
    @eqx.filter_jit
    @eqx.debug.assert_max_traces(max_traces=1)
    def rates(block, y, q):
        return block.node_rhs(y, q), inlet_pressure(block, y, q)

    y = Windkessel3().init()
    for block in (Windkessel3.systemic(), Windkessel3.pulmonary(), Windkessel3(p_venous=1e3)):
        rates(block, y, jnp.asarray(1e-4))


# -- valves ------------------------------------------------------------------------------------


def test_smooth_valve_is_passive():
    """dp q >= 0 for every dp, and no flow at dp = 0: a valve only dissipates. The earlier
    law w softplus(dp / w) / R passed 69 ml/s at dp = 0 (lv-systemic: w 0.5 mmHg, R 0.005
    mmHg s/ml) and 12.7 ml/s forward against dp = -1 mmHg."""
    dp = jnp.concatenate([jnp.linspace(-50, 50, 100001), jnp.asarray([0.0, -0.0])]) * mmHg
    for w, r in itertools.product((0.001, 0.5, 10.0), (1e-4, 0.005, 10.0)):
        valve = Valve(r * R_UNIT, kind="smooth", smoothing=w * mmHg)
        for extra in (0.0, 0.05 * R_UNIT):  # a line resistance in series
            q = np.asarray(valve.flow(dp, extra))
            assert np.all(np.asarray(dp) * q >= 0.0), (w, r, extra)
            # the valve's own drop dp - r q keeps the sign of dp: its loss is >= 0 too
            assert np.all((np.asarray(dp) - extra * q) * q >= 0.0), (w, r, extra)
            assert valve.flow(0.0, extra) == 0.0


def test_smooth_valve_converges_to_ideal():
    """|q - max(dp, 0) / R| = (w / R) x sigmoid(-x), x = |dp| / w, whose largest value is
    W(1/e) = 0.27846 (Lambert W; tests/README.md), at |dp| = 1.27846 w: reached on a fine grid.
    Convergence in w, uniform in dp, and exponentially ideal away from dp = 0."""
    R = 0.01 * R_UNIT
    bound = 0.2784645427610738  # W(1/e), scipy.special.lambertw(exp(-1))
    errors = []
    for w in (1.0, 0.3, 0.1, 0.03, 0.01):
        # a grid of 0 +- 50 mmHg with the two points where the gap peaks
        peaks = jnp.asarray([-1.0, 1.0]) * (1.0 + bound) * w
        dp = jnp.sort(jnp.concatenate([jnp.linspace(-50, 50, 20001), peaks])) * mmHg
        ideal = Valve(R).flow(dp)
        np.testing.assert_allclose(ideal, np.maximum(np.asarray(dp), 0) / R, rtol=1e-14)
        smooth = Valve(R, kind="smooth", smoothing=w * mmHg).flow(dp)
        gap = np.abs(np.asarray(smooth - ideal))
        errors.append(gap.max())
        np.testing.assert_allclose(gap.max(), bound * w * mmHg / R, rtol=1e-12)
        far = np.abs(np.asarray(dp)) > 40 * w * mmHg  # exponentially ideal away from 0
        assert gap[far].max() <= 1e-14 * np.abs(np.asarray(ideal)).max()
    assert all(b < a for a, b in itertools.pairwise(errors))


@pytest.mark.parametrize("kind", ["ideal", "smooth"])
def test_valve_gradients_are_finite_and_extra_resistance_adds(kind):
    valve = Valve(0.01 * R_UNIT, kind=kind, smoothing=0.01 * mmHg)
    for dp in (-50 * mmHg, 0.0, 50 * mmHg):
        g = jax.grad(valve.flow)(jnp.asarray(dp))
        assert np.isfinite(g)
    np.testing.assert_allclose(
        valve.flow(20 * mmHg, 0.03 * R_UNIT), 20 * mmHg / (0.04 * R_UNIT), rtol=1e-12
    )


# -- validation --------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("make", "words"),
    [
        (lambda: Windkessel3(C=-1 * C_UNIT), ["compliance C = -1 ml/mmHg", "(0, inf"]),
        (lambda: Windkessel2(R=0.0), ["resistance R = 0 mmHg s/ml", "(0, inf"]),
        (
            lambda: Windkessel4(R_UNIT, C_UNIT, R_UNIT, -0.01 * mmHg / ml),
            ["inertance L = -0.01 mmHg s^2/ml"],
        ),
        (lambda: Windkessel3(p_venous=float("nan")), ["venous pressure p_venous = nan"]),
        (lambda: WaterColumn(-20 * mm, 30 * mmHg), ["column diameter = -20 mm"]),
        (lambda: WaterColumn(20 * mm, -30 * mmHg), ["column head = -30 mmHg", "[0, inf"]),
        (lambda: Tube(1.0, 0.0), ["tube diameter = 0 mm"]),
        (lambda: Tube(1.0, 10 * mm, loss_coefficient=-1), ["loss coefficient K = -1"]),
        (lambda: Valve(-1e6), ["valve resistance = -0.0075", "mmHg s/ml"]),
        (lambda: Valve(1e6, kind="tanh"), ["'tanh'", "ideal, smooth"]),
        (lambda: Valve(1e6, kind="smooth", smoothing=0.0), ["smoothing width = 0 mmHg"]),
        (lambda: AtrialCompliance(-C_UNIT, 0.0, R_UNIT), ["atrial compliance C = -1 ml/mmHg"]),
        (lambda: preset("accurate"), ["'accurate'", "fast, default, reference"]),
    ],
)
def test_validation_messages(make, words):
    with pytest.raises(ValueError) as info:
        make()
    for word in words:
        assert word in str(info.value)


# -- solve -------------------------------------------------------------------------------------


def test_presets_and_failure_report():
    assert set(PRESETS) == {"fast", "default", "reference"}
    solver, adjoint = diffrax_objects(preset("default", stiff=True))
    assert isinstance(solver, diffrax.Kvaerno5) and isinstance(solver.root_finder, optx.Newton)
    assert isinstance(adjoint, diffrax.RecursiveCheckpointAdjoint)
    assert float(preset("fast").rtol) == 1e-4
    # an explicit solver on a very stiff Windkessel (RC = 1e-9 s) runs out of steps
    stiff = Windkessel2(R=1e-3 * R_UNIT, C=1e-6 * C_UNIT)
    y0 = stiff.init() | {"pc": jnp.asarray(100 * mmHg, dtype=float)}
    with pytest.raises(RuntimeError, match="maximum number of solver steps"):
        respond(stiff, Affine(1e-4), TS, y0=y0, config=REF)
