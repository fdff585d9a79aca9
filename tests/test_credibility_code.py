"""The credibility report's code-verification section: its quick subset meets its checks, and
its observed order of convergence is a real measurement (a second-order method reads ~2)."""

import diffrax
import jax
import pytest

jax.config.update("jax_enable_x64", True)

from cardiosoft.credibility import code_verification as cv  # noqa: E402
from cardiosoft.credibility.evidence import Section  # noqa: E402


def test_quick_section_meets_its_checks_and_reads_order_five(tmp_path):
    section = cv.code_verification(tmp_path, quick=True, progress=lambda m: None)
    assert isinstance(section, Section) and section.key == "code_verification"
    assert section.checks and all(c.met for c in section.checks), section.checks
    order = next(c for c in section.checks if c.name.startswith("observed order"))
    low, high = cv.ORDER_BAND
    assert low <= float(order.value) <= high and low <= 5 <= high and high - low <= 1.0
    for name in section.figures:
        assert (tmp_path / name).stat().st_size > 0 and f"]({name})" in section.text


def test_the_order_computation_reads_two_for_heun():
    # The same field, the same Richardson sequence, a method of known order 2 (Heun: Euler has
    # no error estimate, which the fixed-step controller needs): a wrong step count, a wrong
    # refinement or a wrong logarithm would not read 2 here and 5 above.
    run = cv.convergence("bench-dynamic", diffrax.Heun())
    assert run["steps"] == [cv.BASE_STEPS * k for k in cv.REFINEMENTS]
    assert run["orders"][-1] == pytest.approx(2.0, abs=0.15), run
