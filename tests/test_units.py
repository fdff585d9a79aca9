"""Unit conversions: each constant against an independent definition, not against itself."""

import math

import pytest

from cardiosoft import units
from cardiosoft.units import bpm, cm, deg, minute, ml, mm, mmHg


def test_mmhg_from_its_definition():
    # Conventional mmHg: a 1 mm column of mercury of density 13.5951 g/cm^3 under standard gravity.
    rho_hg = 13.5951e3  # kg/m^3
    assert mmHg == pytest.approx(rho_hg * units.G * 1e-3, rel=1e-12)
    assert units.G == 9.80665


def test_90_mmhg_in_pa():
    # 90 mmHg = 90 * 133.322387415 Pa = 11999.01486735 Pa (exact product of the conventional value).
    assert 90 * mmHg == pytest.approx(11999.01486735, rel=1e-12)
    # 11999.0 Pa to the digits usually quoted: within 0.02 Pa (about 1.2e-6 relative), so the
    # 1e-6 tolerance applies to the exact product above, not to the rounded 11999.0.
    assert abs(90 * mmHg - 11999.0) < 0.02


def test_pressure_reads_back_in_mmhg():
    assert 11999.01486735 / mmHg == pytest.approx(90.0, rel=1e-12)


def test_volume_ml():
    assert ml == 1e-6  # 1 ml = 1 cm^3 = (1e-2 m)^3
    assert ml == pytest.approx(cm**3, rel=1e-15)
    assert 1000 * ml == pytest.approx(1e-3, rel=1e-15)  # one litre in m^3
    assert 108.6e-6 / ml == pytest.approx(108.6, rel=1e-15)


def test_length_mm_cm():
    assert mm == 1e-3
    assert 25.4 * mm == pytest.approx(0.0254, rel=1e-15)  # one inch
    assert 10 * mm == pytest.approx(cm, rel=1e-15)
    assert 0.05 / mm == pytest.approx(50.0, rel=1e-15)


def test_rate_bpm():
    assert 60 * bpm == pytest.approx(1.0, rel=1e-15)  # 60 beats per minute is 1 Hz
    assert 1.0 / (72 * bpm) == pytest.approx(60.0 / 72.0, rel=1e-15)  # period at 72 bpm, s
    # The paper's bench: pull and release in 2 s is 30 bpm.
    assert 1.0 / (30 * bpm) == pytest.approx(2.0, rel=1e-15)
    assert minute * bpm == pytest.approx(1.0, rel=1e-15)  # one beat per minute, over one minute


def test_angle_and_time():
    assert 180 * deg == pytest.approx(math.pi, rel=1e-15)
    assert minute == 60.0
    assert units.s == 1.0 and units.N == 1.0 and units.J == 1.0
