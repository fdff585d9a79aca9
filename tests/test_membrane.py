"""The shell's inflation as a Yeoh membrane (fit/membrane.py): closed forms for the sphere and
the spheroid, convergence in the number of elements, the inner surface, the cables, the data
file and its command line."""

import math

import numpy as np
import pytest
from scipy.integrate import quad

from cardiosoft import datasets
from cardiosoft.files import sha256
from cardiosoft.geometry import Shell, cable_length, cavity_volume
from cardiosoft.units import ml, mm, mmHg
from fit import membrane as mb
from fit.membrane import __main__ as cli

R = 30 * mm  # sphere radius
H = 1.5 * mm  # the paper's wall
C10 = mb.PAPER_YEOH_MPA[0] * 1e6


def _rest_compliance(m):
    """dV/dP (m^3/Pa) of the mid-surface at rest, from the code's tangent."""
    return float(mb.measures(m, mb.rest_state(m)).mid_compliance)


# ------------------------------------------------------------------ the sphere's closed form


@pytest.fixture(scope="module")
def sphere_path():
    """A neo-Hookean hemisphere (symmetry plane at the equator) under volume control from
    lambda = 1.05 to 3, past the pressure's maximum at lambda = 7^(1/6) = 1.383."""
    m = mb.spheroid_membrane(R, R, H, mb.Yeoh(C10), n_elements=96)
    v0 = float(mb.enclosed_volume(m.nodes))
    lam = np.arange(1.05, 3.0001, 0.05)
    states = mb.solve(m, v0 * lam**3, volume_control=True)
    lam_fe = np.array([(float(mb.enclosed_volume(s.x)) / v0) ** (1 / 3) for s in states])
    return m, lam_fe, np.array([float(s.pressure) for s in states])


def test_neo_hookean_sphere_matches_closed_form_past_the_limit_point(sphere_path):
    """P = 4 C10 (H/R)(1/lambda - 1/lambda^7) to 1e-4: the method error is the polygon's
    area-to-volume ratio, O(h^2): 3.0e-4, 7.5e-5, 1.9e-5 with 32, 64, 128 elements (flat in
    lambda), 3.3e-5 with the 96 here."""
    _, lam, p = sphere_path
    exact = 4 * C10 * H / R * (1 / lam - 1 / lam**7)
    assert np.max(np.abs(p / exact - 1)) < 1e-4
    # the path crossed the limit point: the pressure rose, peaked and fell
    peak = 7 ** (1 / 6)
    assert lam[0] < peak < lam[-1]
    assert np.all(np.diff(p[lam < peak]) > 0) and np.all(np.diff(p[lam > peak + 0.05]) < 0)


def test_inner_surface_of_the_inflated_sphere(sphere_path):
    """The cavity inside the inner surface (offset by half the deformed thickness) of the
    inflated hemisphere is the hemisphere of radius lambda R - H / (2 lambda^2). Tolerance: the
    polygon's O(h^2) volume error, 1.4e-4 at rest with 96 elements (measured), so 3e-4."""
    m, lam, _ = sphere_path
    v0 = float(mb.enclosed_volume(m.nodes))
    for i in (0, 10, len(lam) - 1):
        x = m.nodes * lam[i]  # the closed form's state (the FE state is this to O(h^2))
        exact = 2 / 3 * math.pi * (lam[i] * R - H / (2 * lam[i] ** 2)) ** 3
        assert float(mb.inner_volume(m, x)) == pytest.approx(exact, rel=3e-4, abs=0)
        # the mid-surface volume is exact for the polygon: lambda^3 v0
        assert float(mb.enclosed_volume(x)) == pytest.approx(lam[i] ** 3 * v0, rel=1e-12, abs=0)


# ------------------------------------------------------------- linear membrane theory at rest


def _clapeyron_compliance(a, b, thickness, c10):
    """dV/dP of a complete spheroid (axial semi-axis a, equatorial b) in linear membrane theory,
    independent of fit.membrane: the statically determinate resultants N_phi = p r2 / 2,
    N_theta = p r2 (1 - r2 / (2 r1)), Hooke's law with E = 6 C10 and nu = 1/2, and Clapeyron's
    theorem p dV / 2 = strain energy = int (N_phi^2 + N_theta^2 - 2 nu N_phi N_theta) / (2 E h)
    dA."""
    e, nu = 6 * c10, 0.5

    def integrand(psi):  # meridian (r, z) = (b cos psi, a sin psi)
        r = b * math.cos(psi)
        ds = math.hypot(b * math.sin(psi), a * math.cos(psi))
        n_r = (math.cos(psi) / b) / math.hypot(math.cos(psi) / b, math.sin(psi) / a)
        r2 = r / n_r  # along the normal to the axis
        r1 = ds**3 / (a * b)  # the meridian's radius of curvature
        n_phi, n_theta = r2 / 2, r2 * (1 - r2 / (2 * r1))
        return (n_phi**2 + n_theta**2 - 2 * nu * n_phi * n_theta) * 2 * math.pi * r * ds

    half, _ = quad(integrand, 0, math.pi / 2, epsabs=0, epsrel=1e-13)
    return 2 * half / (e * thickness)


@pytest.mark.parametrize(
    "a, b",
    [(R, R), (60.75 * mm, 30.75 * mm)],  # the sphere; the paper's mid-surface as a spheroid
    ids=["sphere", "prolate-spheroid"],
)
def test_slope_at_rest_matches_linear_membrane_theory(a, b):
    """The tangent dV/dP at rest of a complete spheroid (two halves by symmetry), with the
    paper's Yeoh law (at rest only C10 counts), against Clapeyron's closed form; for the sphere
    also against 2 pi R^4 (1 - nu) / (E h). Tolerance 1e-4: the O(h^2) method error measured,
    4.2e-5 (sphere) and 5.7e-5 (spheroid) with 128 elements, 4x less per doubling."""
    m = mb.spheroid_membrane(a, b, H, mb.paper_yeoh(), n_elements=128)
    exact = _clapeyron_compliance(a, b, H, C10)
    if a == b:
        assert exact == pytest.approx(2 * math.pi * R**4 * 0.5 / (6 * C10 * H), rel=1e-12, abs=0)
    assert 2 * _rest_compliance(m) == pytest.approx(exact, rel=1e-4, abs=0)


def test_tangent_is_the_nonlinear_solutions_slope():
    """The tangent compliance (implicit differentiation) against the nonlinear solve's secant
    at 0.01 mmHg: they differ by the curve's own O(P) change, 2.1e-5 relative (measured)."""
    m = mb.spheroid_membrane(60.75 * mm, 30.75 * mm, H, mb.paper_yeoh(), n_elements=32)
    (state,) = mb.solve(m, [0.01 * mmHg])
    secant = (float(mb.enclosed_volume(state.x)) - float(mb.enclosed_volume(m.nodes))) / (
        0.01 * mmHg
    )
    assert secant == pytest.approx(_rest_compliance(m), rel=1e-4, abs=0)


# ------------------------------------------------------------------------- the paper's shell

STUDY = np.array([30.0, 90.0, 150.0, 250.0]) * mmHg


@pytest.fixture(scope="module")
def shell_50():
    return mb.inflation(STUDY, n_elements=50)


def test_shell_swelling_converges_in_elements(shell_50):
    """N = 50 and 100 agree to 0.1 % in swelling (measured: 3.8e-4 at 30 mmHg, 3.2e-4 at 250),
    and so in volume (108.6 ml + swelling). The shipped N: the slow test below."""
    fine = mb.inflation(STUDY, n_elements=100)
    np.testing.assert_allclose(shell_50.swelling, fine.swelling, rtol=1e-3)


@pytest.mark.slow
def test_shipped_element_count_converged():
    """N and 2N at the shipped N (200): measured 2e-5 relative in swelling."""
    n = mb.N_ELEMENTS
    a, b = mb.inflation(STUDY, n), mb.inflation(STUDY, 2 * n)
    np.testing.assert_allclose(a.swelling, b.swelling, rtol=1e-3)


def test_shell_is_taut_and_the_curve_softens_then_stiffens():
    """A membrane is valid where both principal tensions are positive (else it wrinkles); the
    Yeoh law's softening gives a tangent compliance that grows to ~230 mmHg and then falls."""
    r = mb.inflation(np.arange(0.0, 401.0, 25.0) * mmHg, n_elements=50)
    assert np.all(r.min_tension[1:] > 0)
    assert np.all(np.diff(r.swelling) > 0)
    i = int(np.argmax(r.compliance))
    assert 150 * mmHg < r.pressure[i] < 300 * mmHg
    assert r.compliance[-1] < 0.8 * r.compliance[i]
    assert r.max_stretch[-1] < 1.5  # inside the material tests' 50 % strain (Sec. II-D)


def test_continuation_step_does_not_change_the_curve():
    """Pressure steps of 1 and 20 mmHg reach the same equilibria to Newton's tolerance (1e-10
    of the radius). Full Newton steps along the membrane's soft zig-zag modes land on spurious
    folded states (measured without the step limit and the stability check: the 1-mmHg path
    left the curve at 80 mmHg, 116.2 instead of 127.4 ml); either protection keeps the path."""
    m = mb.shell_membrane(30)
    p = np.arange(20.0, 301.0, 20.0) * mmHg
    fine = mb.solve(m, p, max_step=1 * mmHg)
    coarse = mb.solve(m, p, max_step=20 * mmHg)
    for a, b in zip(fine, coarse, strict=True):
        np.testing.assert_allclose(a.x, b.x, rtol=0, atol=1e-9 * R)


def test_inputs_are_checked():
    with pytest.raises(ValueError, match=r"pressure = -1 mmHg is outside .*\[0, 2000\] mmHg"):
        mb.inflate([0.0, -1 * mmHg], n_elements=8)
    with pytest.raises(ValueError, match=r"n_elements = 3 is outside the allowed range \[4, inf\)"):
        mb.inflate([10 * mmHg], n_elements=3)
    with pytest.raises(ValueError, match=r"restrain_omega = -1 is outside .*\[0, 50\]"):
        mb.inflation([10 * mmHg], n_elements=8, restrain_omega=-1.0)
    with pytest.raises(ValueError, match="must not decrease"):
        mb.solve(mb.shell_membrane(8), [20 * mmHg, 10 * mmHg])


def test_inflation_curve_in_si():
    """The curve the fit reads: pressures (Pa) from 0 every step, volumes (m^3) from the
    paper's unloaded cavity, the same as inflate's."""
    p, v = mb.inflation_curve(p_max=20 * mmHg, step=10 * mmHg, n_elements=8)
    np.testing.assert_allclose(p, [0.0, 10 * mmHg, 20 * mmHg], rtol=1e-15)
    assert v[0] == pytest.approx(float(cavity_volume(Shell())), rel=1e-12, abs=0)
    np.testing.assert_allclose(v, mb.inflate(p, n_elements=8), rtol=1e-12)
    assert np.all(np.diff(v) > 0)


# ---------------------------------------------------------------------------------- cables


@pytest.mark.parametrize("omega", [1.0, 4.0, 6.0])
def test_cable_embedding_at_rest_is_the_papers_helix(omega):
    """The material curve of the mesh at rest has the length of eq. (3): the mesh's O(h^2) and
    the polyline's O(1/M^2) errors, 1.7e-5 measured at Omega 4 with 100 elements, so 1e-4."""
    shell = Shell()
    m = mb.shell_membrane(100)
    e = mb.embed_helix(shell, 100, omega)
    length = float(mb.cable_length(m, e, m.nodes))
    assert length == pytest.approx(float(cable_length(shell, omega)), rel=1e-4, abs=0)


@pytest.mark.slow
def test_restrained_cables_keep_their_length():
    """Held at their rest length, the six cables pull (tension > 0) and the shell swells less."""
    shell = Shell()
    p = [30 * mmHg]
    held = mb.inflation(p, 30, restrain_omega=4.0)
    free = mb.inflation(p, 30)
    assert held.cable_tension[0] > 0
    assert held.swelling[0] < 0.5 * free.swelling[0]
    m = mb.shell_membrane(30)
    e = mb.embed_helix(shell, 30, 4.0)
    (state,) = mb.solve(m, p, cable=(e, mb.cable_length(m, e, m.nodes)))
    assert float(mb.cable_length(m, e, state.x)) == pytest.approx(
        float(mb.cable_length(m, e, m.nodes)), rel=1e-9, abs=0
    )


# ------------------------------------------------------------------- the data file and CLI


def test_shipped_file():
    d = datasets.load_paper_data().membrane_inflation
    assert d.kind == "membrane_inflation"
    assert d.sha256 == sha256(d.path)
    assert datasets.load_paper_data().hashes()[d.path.name] == d.sha256
    p, v, s = d["pressure_mmHg"], d["volume_ml"], d["swelling_ml"]
    assert p[0] == 0 and p[-1] >= 250
    assert v[0] == pytest.approx(float(cavity_volume(Shell())) / ml, abs=5e-5)
    np.testing.assert_allclose(v - v[0], s, atol=1.5e-4)  # each printed to 1e-4
    assert np.all(np.diff(v) > 0) and np.all(d["compliance_ml_per_mmHg"] > 0)
    assert all(
        "python -m fit.membrane" in t and f"{mb.N_ELEMENTS} linear elements" in t
        for t in d.provenance
    )


@pytest.mark.slow
def test_shipped_file_is_the_modules_output():
    """The shipped curve regenerated at its element count: equal to its printed digits."""
    d = datasets.load_paper_data().membrane_inflation
    keep = np.isin(d["pressure_mmHg"], [30, 90, 150, 250])
    r = mb.inflation(d["pressure_mmHg"][keep] * mmHg)
    np.testing.assert_allclose(r.volume / ml, d["volume_ml"][keep], rtol=0, atol=6e-5)


def test_cli_writes_a_loadable_file_and_refuses_to_overwrite(tmp_path, capsys):
    out = tmp_path / "membrane_inflation_small.csv"
    args = ["--out", str(out), "--elements", "8", "--p-max", "20", "--step", "10"]
    assert cli.main(args) == 0
    d = datasets.load(out)
    assert d.kind == "membrane_inflation"
    np.testing.assert_array_equal(d["pressure_mmHg"], [0, 10, 20])
    assert "python -m fit.membrane --elements 8 --p-max 20 --step 10" in d.provenance[0]
    printed = capsys.readouterr().out
    assert sha256(out) in printed
    before = out.read_bytes()
    assert cli.main(args) == 2  # exists: refused without --force
    assert out.read_bytes() == before
    assert "--force" in capsys.readouterr().err
    assert cli.main([*args, "--force"]) == 0


@pytest.mark.parametrize(
    "bad, message",
    [
        (["--elements", "2"], "--elements = 2"),
        (["--p-max", "-5"], "pressure = -5 mmHg"),
        (["--step", "0"], "--step = 0 mmHg"),
    ],
)
def test_cli_bad_input_exits_2_and_writes_nothing(tmp_path, capsys, bad, message):
    out = tmp_path / "m.csv"
    assert cli.main(["--out", str(out), *bad]) == 2
    assert not out.exists()
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1


def test_malformed_membrane_file_is_refused(tmp_path):
    path = tmp_path / "membrane_inflation_mine.csv"
    path.write_text("pressure_mmHg,volume_ml,provenance\n0,108.6,mine\n0,109.0,mine\n")
    with pytest.raises(ValueError, match="duplicate row"):
        datasets.load(path)
    path.write_text("pressure_mmHg,volume_ml,provenance\n-3,108.6,mine\n")
    with pytest.raises(ValueError, match="column 'pressure_mmHg'"):
        datasets.load(path)
