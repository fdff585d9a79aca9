"""``cardiosoft.solve``: what the integrator does with forcing it cannot see coming, and the
implicit derivative of a periodic orbit against an analytic one."""

import re

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cardiosoft.circulation import Windkessel3
from cardiosoft.shooting import orbit_beat
from cardiosoft.solve import (
    SUCCESSFUL,
    SolverConfig,
    diffrax_objects,
    ran_out_of_steps,
    respond,
    result_code,
    result_code_of,
    result_message,
)
from cardiosoft.units import ml as ml_si
from cardiosoft.units import mmHg

PERIOD, EJECTION, SV = 0.8, 0.3, 70e-6  # s, s, m^3
RP, C, RD = 6.67e6, 1.5e-8, 1.33e8  # Pa s/m^3, m^3/Pa, Pa s/m^3


class HalfSine(eqx.Module):
    """A half-sine ejection of volume ``sv`` over ``ejection`` s, once per ``period``."""

    sv: jax.Array
    period: jax.Array
    ejection: jax.Array

    def __call__(self, t):
        tau = jnp.mod(t, self.period)
        peak = self.sv * jnp.pi / (2 * self.ejection)
        return jnp.where(tau < self.ejection, peak * jnp.sin(jnp.pi * tau / self.ejection), 0.0)


def test_a_result_leaves_a_program_as_diffraxs_own_code():
    """Beats and batch solutions carry diffrax's result as its integer code, so that a stored
    program's output is rebuilt without importing diffrax (issue #41): SUCCESSFUL is diffrax's
    own code, and a code reads back as diffrax's message."""
    assert int(result_code(diffrax.RESULTS.successful)) == SUCCESSFUL
    code = result_code_of("max_steps_reached")
    assert code != SUCCESSFUL
    expected = str(diffrax.RESULTS[diffrax.RESULTS.max_steps_reached]).strip()
    assert result_message(code) == expected and "maximum number of solver steps" in expected


def test_ran_out_of_steps_reads_the_codes():
    codes = np.array([SUCCESSFUL, result_code_of("max_steps_reached"), SUCCESSFUL])
    assert ran_out_of_steps(codes).tolist() == [False, True, False]
    assert ran_out_of_steps(np.full(2, SUCCESSFUL)).tolist() == [False, False]


@pytest.mark.parametrize(
    ("config", "named"),
    [
        (SolverConfig(solver="tsit5"), "SolverConfig solver = 'tsit5'"),
        (SolverConfig(solver="ForwardMode"), "SolverConfig solver = 'ForwardMode'"),
        (SolverConfig(adjoint="forward"), "SolverConfig adjoint = 'forward'"),
    ],
)
def test_a_solver_or_adjoint_name_diffrax_lacks_is_refused_by_name(config, named):
    with pytest.raises(ValueError, match=re.escape(named)):
        diffrax_objects(config)


@pytest.mark.parametrize("with_kinks", [False, True])
def test_a_pulse_between_two_steps_does_not_vanish(with_kinks):
    """Mean inlet pressure of a 3-element Windkessel at its periodic steady state: the
    capacitor passes no net flow over a period, so it is mean(q) (Rp + Rd) = 91.7 mmHg whatever
    the pulse's shape. Without a step cap and without the kinks, the solver stepped over whole
    pulses: 4.5 mmHg. Averaged over the last 5 of 20 periods, the transient (time constant
    Rd C = 2 s) has decayed to e^-6 of its start, and the samples (every 8 ms) average the
    pulse to ~0.1 %: 1 % holds with room."""
    ts = jnp.linspace(0.0, 20 * PERIOD, 2001)[1:]
    kinks = jnp.sort(jnp.concatenate([jnp.arange(21) * PERIOD, jnp.arange(20) * PERIOD + EJECTION]))
    q = HalfSine(jnp.asarray(SV), jnp.asarray(PERIOD), jnp.asarray(EJECTION))
    p = respond(Windkessel3(RP, C, RD), q, ts, jump_ts=kinks if with_kinks else None)
    mean = float(jnp.mean(p[ts > 15 * PERIOD]))
    expected = SV / PERIOD * (RP + RD)
    assert mean == pytest.approx(expected, rel=1e-2), (mean / mmHg, expected / mmHg)


def test_the_step_cap_can_be_lifted_and_then_pulses_are_lost():
    """The cap is what keeps them: without it (max_step=None) the same run is far off."""
    ts = jnp.linspace(0.0, 20 * PERIOD, 2001)[1:]
    q = HalfSine(jnp.asarray(SV), jnp.asarray(PERIOD), jnp.asarray(EJECTION))
    p = respond(Windkessel3(RP, C, RD), q, ts, max_step=None)
    mean = float(jnp.mean(p[ts > 15 * PERIOD]))
    assert mean < 0.5 * SV / PERIOD * (RP + RD)


GUARD = """
import jax, jax.numpy as jnp
jax.config.update("jax_enable_x64", True)
from cardiosoft.periodic import periodic_beats
from cardiosoft.solve import SUCCESSFUL

field = lambda t, y, args: {"volume": -y["volume"] + 1e-6 * jnp.sin(2 * jnp.pi * t)}

@jax.jit
def run(ts):
    out = periodic_beats(
        field, {"volume": jnp.array(1e-6)}, 1.0, ts, jump_ts=jnp.array([0.5]),
        total_volume=lambda y: y["volume"], max_beats=3, tol=0.0,
    )
    return out.result == SUCCESSFUL, jnp.all(jnp.isfinite(out.observed["volume"]))

print(*(bool(v) for v in run(jnp.array([0.0, 0.5, 1.0]))))
print(*(bool(v) for v in run(jnp.array([0.0, 0.5, 0.4, 1.0]))))  # not increasing
"""


def test_samples_lost_to_a_nan_resolved_check_are_a_failure_not_a_result():
    """With EQX_ON_ERROR=nan (the command lines', cardiosoft._cli), diffrax's check of the save
    times gives inf samples and success; periodic_beats reports the solve as failed."""
    import os
    import subprocess
    import sys

    env = {**os.environ, "EQX_ON_ERROR": "nan"}
    out = subprocess.run(
        [sys.executable, "-c", GUARD], env=env, capture_output=True, text=True, timeout=300
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.split("\n")[:2] == ["True True", "False False"]


class Forced(eqx.Module):
    """dV/dt = -k V + a sin(2 pi t / T): a linear volume relaxing at rate k, forced periodically.
    Its periodic orbit is V*(t) = a (k sin wt - w cos wt) / (k^2 + w^2), w = 2 pi / T."""

    a: jax.Array
    k: float = eqx.field(static=True)
    period: float = eqx.field(static=True)

    def __call__(self, t, y, args):
        w = 2 * jnp.pi / self.period
        return {"volume": -self.k * y["volume"] + self.a * jnp.sin(w * t)}

    def orbit(self, t):
        w = 2 * jnp.pi / self.period
        return self.a * (self.k * jnp.sin(w * t) - w * jnp.cos(w * t)) / (self.k**2 + w**2)


def _orbit_beat(field, y_start, ts):
    config = SolverConfig(rtol=1e-11, atol=1e-18, adjoint=diffrax.ForwardMode())
    return orbit_beat(
        field, y_start, field.period, ts, jump_ts=jnp.array([0.5 * field.period]),
        total_volume=lambda y: y["volume"], v_ref=y_start["volume"], closed=False,
        config=config,
    )


def test_orbit_beat_differentiates_the_orbit_not_the_beat():
    """From the orbit's own start, one beat's derivative with respect to the forcing a is the
    orbit's, V*(t) / a (V* is linear in a), though the start is held: the implicit function
    theorem. One beat from that start held fixed would add the transient e^(-k t) (37 % after a
    beat at k = 1/s): the derivative at t = T would be V*(0) / a (1 - e^(-kT)). Tolerance: the
    solver's rtol 1e-11, with room for the implicit step's linear solve."""
    a, k, period = 2e-6, 1.0, 1.0
    ts = jnp.linspace(0.0, period, 9)

    def observed(a):
        field = Forced(a, k, period)
        start = {"volume": Forced(jnp.asarray(2e-6), k, period).orbit(0.0)}
        return _orbit_beat(field, start, ts).observed["volume"]

    values, tangent = jax.jvp(observed, (jnp.asarray(a),), (jnp.asarray(1.0),))
    exact = Forced(jnp.asarray(a), k, period).orbit(ts)
    np.testing.assert_allclose(values, exact, rtol=1e-8)
    np.testing.assert_allclose(tangent, exact / a, rtol=1e-8)


def test_orbit_beat_without_an_isolated_orbit_has_nan_derivatives_not_wrong_ones():
    """k = 0: every start is periodic (dV/dt = a sin wt), so dPhi/du - I = 0 is singular and the
    orbit has no derivative. The values stay finite; the observed derivatives are NaN."""
    ts = jnp.linspace(0.0, 1.0, 5)

    def observed(a):
        out = _orbit_beat(Forced(a, 0.0, 1.0), {"volume": jnp.asarray(1e-6)}, ts)
        return out.observed["volume"]

    values, tangent = jax.jvp(observed, (jnp.asarray(2e-6),), (jnp.asarray(1.0),))
    assert bool(jnp.all(jnp.isfinite(values)))
    assert bool(jnp.all(jnp.isnan(tangent)))


def test_shooting_that_stops_short_of_its_tolerance_goes_on_from_newtons_last_iterate():
    """Newton can stop short of its own tolerance, much nearer the orbit than its guess (on a
    closed loop's kinked map it stalls at the integrator's noise). On a slow linear relaxation
    (k = 0.02 per beat) one Newton step from a 2-beat guess lands on the orbit, and one is all
    it is allowed: the beats go on from there, 2 to the steady test, V(0) on the analytic orbit
    to the solver's tolerance (rtol 1e-11, here 1e-9 of the orbit's amplitude). From the guess
    instead (0.3 ml off the orbit), each beat closes 2 % of the distance, a change below the
    steady tolerance of 0.01 ml: the beats would stop at once, 0.3 ml off."""
    from cardiosoft.shooting import shoot_periodic

    field = Forced(jnp.asarray(2e-6), 0.02, 1.0)
    config = SolverConfig(rtol=1e-11, atol=1e-18, adjoint=diffrax.ForwardMode())
    out = jax.jit(
        lambda y0: shoot_periodic(
            field, y0, 1.0, None, jump_ts=None, total_volume=lambda y: y["volume"],
            closed=False, guess_beats=2, max_beats=200, tol=0.01, config=config, max_newton=1,
        )
    )({"volume": jnp.zeros(())})
    assert int(out.newton_steps) == 1 and int(out.beats) == 2 + 2
    np.testing.assert_allclose(out.y0["volume"], field.orbit(0.0), rtol=1e-9)


def test_a_queued_batch_gives_each_member_the_beats_it_gets_alone():
    """``periodic_beats_batch`` on a batch larger than its lanes (40 members on
    ``queue_lanes(40)`` lanes): each member's beat count, residual and last beat are those of
    ``periodic_beats`` on that member alone (the side-by-side batch, a second implementation),
    and its beat count the linear relaxation's own. Rates k from 0.02 to 4 per beat: some
    members settle in 4 beats, the slowest never within ``max_beats`` (reported so)."""
    from cardiosoft.periodic import BeatProblem, periodic_beats, periodic_beats_batch, queue_lanes

    a, tol, max_beats = 1e-6, 1e-4, 80  # m^3 (1 ml), ml (the change's unit), beats
    ks = jnp.geomspace(4.0, 0.02, 40)[jnp.array([*range(0, 40, 2), *range(1, 40, 2)])]
    ts = jnp.linspace(0.0, 1.0, 5)

    def problem(k):
        def field(t, y, args):
            return {"volume": -k * y["volume"] + a * jnp.sin(2 * jnp.pi * t)}

        return BeatProblem(field, {"volume": jnp.zeros(())}, 1.0, ts, None, None)

    settings = dict(max_beats=max_beats, tol=tol)
    queued = jax.jit(lambda ks: periodic_beats_batch(problem, ks, **settings))(ks)
    alone = jax.jit(jax.vmap(lambda k: periodic_beats(*problem(k)[:4], jump_ts=None,
                                                       total_volume=None, **settings)))(ks)
    assert queue_lanes(40) < 40
    np.testing.assert_array_equal(queued.beats, alone.beats)
    # the same steps of the same solver; round-off apart (the lanes' vector width differs)
    np.testing.assert_allclose(queued.observed["volume"], alone.observed["volume"], rtol=1e-12)
    np.testing.assert_allclose(queued.residual, alone.residual, rtol=1e-6)
    # analytically, beat n changes V by |V*(0)| e^{-k (n-1)} (1 - e^{-k}) from V(0) = 0, and
    # the loop stops after the first beat whose predecessor changed V by at most tol
    w = 2 * np.pi
    start = np.abs(a * w / (np.asarray(ks) ** 2 + w**2)) / ml_si
    for k, s, beats in zip(np.asarray(ks), start, np.asarray(queued.beats), strict=True):
        changes = s * np.exp(-k * np.arange(max_beats)) * (1 - np.exp(-k))
        settled = np.flatnonzero(changes <= tol)
        expected = max_beats if not settled.size else min(max(settled[0] + 2, 2), max_beats)
        assert abs(int(beats) - expected) <= 1, (k, beats, expected)  # the threshold's round-off
    assert int(queued.beats.min()) == 4 and int(queued.beats.max()) == max_beats


SHARDED_QUEUE = """
import json, jax, jax.numpy as jnp, numpy as np
jax.config.update("jax_enable_x64", True)
from cardiosoft.beat_solution import shard
from cardiosoft.periodic import BeatProblem, periodic_beats_batch

assert jax.device_count() == 2
ks = shard(jnp.geomspace(4.0, 0.02, 80))

def problem(k):
    def field(t, y, args):
        return {"volume": -k * y["volume"] + 1e-6 * jnp.sin(2 * jnp.pi * t)}
    return BeatProblem(field, {"volume": jnp.zeros(())}, 1.0, jnp.linspace(0, 1, 5), None, None)

out = jax.jit(lambda ks: periodic_beats_batch(problem, ks, max_beats=80, tol=1e-4))(ks)
print(json.dumps({"beats": np.asarray(out.beats).tolist(),
                  "volume": np.asarray(out.observed["volume"]).tolist()}))
"""


def test_a_batch_sharded_over_two_devices_gives_each_member_its_own_beats():
    """The sweeps shard a chunk over the cores' devices; ``periodic_beats_batch`` then runs a
    queue on each (``jax.shard_map``). In a process with two host devices, 80 members (40 a
    device, more than its lanes) get the beats and last beat that ``periodic_beats`` gives
    each alone, here side by side on one device."""
    import json
    import os
    import subprocess
    import sys

    from cardiosoft.periodic import BeatProblem, periodic_beats

    flags = os.environ.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=2"
    run = subprocess.run(
        [sys.executable, "-c", SHARDED_QUEUE], env={**os.environ, "XLA_FLAGS": flags},
        capture_output=True, text=True, timeout=600,
    )
    assert run.returncode == 0, run.stderr
    sharded = json.loads(run.stdout.strip().splitlines()[-1])
    ks = jnp.geomspace(4.0, 0.02, 80)

    def alone(k):
        def field(t, y, args):
            return {"volume": -k * y["volume"] + 1e-6 * jnp.sin(2 * jnp.pi * t)}

        p = BeatProblem(field, {"volume": jnp.zeros(())}, 1.0, jnp.linspace(0, 1, 5), None, None)
        return periodic_beats(*p[:4], jump_ts=None, total_volume=None, max_beats=80, tol=1e-4)

    expected = jax.jit(jax.vmap(alone))(ks)
    np.testing.assert_array_equal(sharded["beats"], expected.beats)
    assert len(set(sharded["beats"])) > 10  # members that settle at many different beats
    # the same steps; round-off apart (the lanes' vector width differs)
    np.testing.assert_allclose(sharded["volume"], expected.observed["volume"], rtol=1e-12)
