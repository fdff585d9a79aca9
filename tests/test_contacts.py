"""The shell's two contacts (issue #39, item 6): a cable only pulls (``cable_slack``,
:class:`cardiosoft.circuit.CableSlack`), and the walls meet (``wall_contact``,
:class:`cardiosoft.circuit.WallContact`). Each on a problem whose answer is known, then the
bench at a rate where neither acts (30 bpm) and at one where both do (120 bpm).
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cardiosoft.batch import solve_beats
from cardiosoft.circuit import CableSlack, WallContact
from cardiosoft.experiment import configure
from cardiosoft.scene import load_scene
from cardiosoft.units import ml, mmHg

SLACK = CableSlack()
MU_L_FR = 1e-6 * 1e-3 * 1.0  # mu l F_r (N m): the smoothed contact's g T
K, REST = 2000.0, 0.02  # a spring shell: F(x) = K (x - REST), free where x = REST (N/m, m)
STROKE = 0.046


def spring_force(rest):
    return lambda x: K * (x - rest)


def smoothed_spring(disk):
    """The smoothed problem's closed form on the spring: the gap g > 0 with
    ``K (disk + g - REST) g = mu l F_r``, and its tension."""
    a, c = K * (disk - REST), K * MU_L_FR
    root = np.sqrt(a**2 + 4.0 * c)
    # the root of T^2 - a T - c = 0 in the form without cancellation for either sign of a
    tension = 0.5 * (a + root) if a > 0 else 2.0 * c / (root - a)
    return disk + MU_L_FR / tension, tension


@pytest.mark.parametrize("disk", [0.0, 0.012, 0.0199, 0.021, 0.03, 0.046])
def test_the_shell_pull_solves_the_smoothed_contact(disk):
    pull, tension = SLACK.shell_pull(spring_force(REST), jnp.asarray(disk), STROKE)
    expected_pull, expected_tension = smoothed_spring(disk)
    assert float(tension) > 0.0
    # slack, the tension K (x_s - REST) ~ 1e-8 N is a difference of pulls ~0.02 m: its
    # round-off is eps x_s / (x_s - REST) ~ 1e-7 relative
    np.testing.assert_allclose(float(tension), expected_tension, rtol=1e-6)
    np.testing.assert_allclose(float(pull), expected_pull, rtol=1e-12)


@pytest.mark.parametrize("disk", [0.0, 0.012, 0.0199, 0.021, 0.03, 0.046])
def test_the_smoothing_is_the_ideal_cable_to_a_micrometre(disk):
    pull, tension = SLACK.shell_pull(spring_force(REST), jnp.asarray(disk), STROKE)
    # ideal: slack, the shell at its free position with no tension; taut, at the disk
    ideal_pull, ideal_tension = max(disk, REST), K * max(disk - REST, 0.0)
    assert abs(float(pull) - ideal_pull) <= 1e-6
    assert abs(float(tension) - ideal_tension) <= K * 1e-6


def test_the_shell_pull_differentiates_by_the_implicit_function_theorem():
    def slack_pull(rest):
        return SLACK.shell_pull(spring_force(rest), jnp.asarray(0.01), STROKE)[0]

    def taut_tension(disk):
        return SLACK.shell_pull(spring_force(REST), disk, STROKE)[1]

    # slack, the shell follows its own free position; taut, the tension grows with the spring
    assert float(jax.grad(slack_pull)(REST)) == pytest.approx(1.0, rel=1e-6)
    assert float(jax.grad(taut_tension)(0.03)) == pytest.approx(K, rel=1e-6)


def test_the_wall_is_absent_above_its_onset_and_linear_in_full_contact():
    wall = WallContact()
    onset, e_w = float(wall.onset), float(wall.stiffness)
    above = jnp.linspace(onset, 120 * ml, 7)
    assert np.all(np.asarray(wall.energy(above)) == 0.0)
    assert np.all(np.asarray(wall.pressure(above)) == 0.0)
    # in full contact (from V = 0 down) the depth is onset / 2 - V: the pressure is linear
    below = jnp.asarray([0.0, -0.5 * onset, -onset])
    np.testing.assert_allclose(wall.pressure(below), -e_w * (0.5 * onset - below), rtol=1e-12)
    # in between a C2 onset: the pressure and its slope run continuously into both sides
    v = jnp.linspace(-0.1 * onset, 1.1 * onset, 801)
    slope = np.diff(np.asarray(wall.pressure(v))) / np.diff(np.asarray(v))
    assert np.all(slope >= 0.0) and np.max(np.abs(np.diff(slope))) <= 0.02 * e_w


@pytest.fixture(scope="module")
def rates():
    """30 and 120 bpm at 90 mmHg, and 120 bpm at 30 mmHg, whose column empties the chamber,
    with both contacts and without (energy kept)."""
    bare = load_scene("bench-dynamic")
    contacts = configure(bare, effects=["cable_slack", "wall_contact"])  # --add-effect ...
    kwargs = dict(
        bpm=jnp.asarray([30.0, 120.0, 120.0]),
        afterload=jnp.asarray([90.0, 90.0, 30.0]) * mmHg,
        save="traces",
        steady="shooting",  # the walls' water hammer rings: beat after beat is slow there
        energy=True,
    )
    return solve_beats(contacts, **kwargs), solve_beats(bare, **kwargs)


@pytest.mark.slow  # the rates fixture: 100 s of CI's 20 minutes
def test_where_neither_acts_the_beat_is_the_one_without_them(rates):
    slack, taut = rates
    assert bool(slack.succeeded[0]) and bool(taut.succeeded[0])
    assert float(taut.metrics.min_cable_force[0]) > 1.0  # taut at 30 bpm, > 1 N throughout
    assert float(taut.metrics.esv[0]) > float(WallContact().onset)  # the wall is absent
    for name in (
        "stroke_volume",
        "ejection_fraction",
        "peak_force",
        "mech_work",
        "esv",
        "max_pump_pressure",
        "min_pump_pressure",
        "efficiency",
    ):
        a, b = (float(getattr(s.metrics, name)[0]) for s in (slack, taut))
        # the slack of a taut cable is mu l F_r / T <= 1e-9 m: its effect is ~1e-9 relative
        assert a == pytest.approx(b, rel=1e-6), name


@pytest.mark.slow  # the rates fixture: 100 s of CI's 20 minutes
def test_at_120_bpm_the_cables_slacken_instead_of_pushing(rates):
    slack, taut = rates
    assert float(taut.metrics.min_cable_force[1]) < -5.0  # the taut model's cable pushes
    force = np.asarray(slack.traces["cable_force"][1])
    assert force.min() > 0.0  # a tension, positive by construction
    shell, disk = (np.asarray(slack.traces[k][1]) for k in ("shell_pull", "pull"))
    assert np.all(shell >= disk)
    assert (shell - disk).max() > 1e-3  # slack by more than a millimetre at times
    # the slack changes the beat: the shell recoils on its own, ahead of the disk
    assert float(slack.metrics.peak_force[1]) < 0.95 * float(taut.metrics.peak_force[1])
    assert float(slack.metrics.esv[1]) > float(WallContact().onset)  # the slack alone


@pytest.mark.slow  # the rates fixture: 100 s of CI's 20 minutes
def test_at_120_bpm_and_30_mmhg_the_walls_meet_instead_of_passing_through(rates):
    contacts, bare = rates
    assert float(bare.metrics.esv[2]) < -1 * ml  # the bare chamber's volume goes below zero
    assert bool(contacts.succeeded[2]) and float(contacts.residual[2]) <= contacts.steady_tol
    assert float(contacts.metrics.esv[2]) >= 0.0
    assert 0.9 < float(contacts.metrics.ejection_fraction[2]) <= 1.0


@pytest.mark.slow  # the rates fixture: 100 s of CI's 20 minutes
def test_with_the_contacts_volume_and_energy_still_close(rates):
    slack, taut = rates
    assert float(jnp.max(slack.volume_drift)) <= 1e-9
    # the account closes to the solver's tolerance, as it does without the contacts: the
    # shell stores U(V, x_s) at its own pull, not the disk's (and the contact mu l F_r log g,
    # ~1e-8 J over a beat), and the walls their U_w
    for i in range(3):
        assert (
            float(slack.metrics.energy_residual[i])
            <= 2 * float(taut.metrics.energy_residual[i]) + 1e-4
        )
