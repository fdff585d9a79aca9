"""Design optimisation (``cardiosoft.design``, issue #13).

The in-process tests share one problem shape (three targets, 30/60/90 mmHg at 60 bpm, Omega
and C free) so that the search compiles once for all of them, and the verifying ``run()`` once
too (the finite differences of the gradient test are ``run()``s of the same shape):

- the gradient of the periodic steady state's stroke volume (Newton shooting, implicit
  derivative), as the search uses it, against central differences of independently
  converged runs;
- recovery of the stroke volumes of a known design from the default design (several targets
  at once, one design);
- an unreachable target: no NaN, ``reached`` False, the closest design and the range seen.

Bad input is checked through the API (no solve) and through the command line (one line, exit
2, nothing written). The end-to-end test runs ``python -m cardiosoft.design --out`` and checks
its ``design.json`` against an independent ``python -m cardiosoft.simulate`` of the design it
names (two fresh processes, each compiling: marked slow: about 55 s on two busy cores).
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import cardiosoft as cs
from cardiosoft import design
from cardiosoft.units import ml

REPO = Path(__file__).resolve().parent.parent
HEADS = [30.0, 60.0, 90.0]
BPM = 60.0
KNOWN = {"omega": 3.2, "shortening": 0.45}


@pytest.fixture(scope="module")
def pump():
    return cs.load_pump()


@pytest.fixture(scope="module")
def known_svs(pump):
    """The stroke volumes (ml) of the design KNOWN at HEADS, by the ordinary run() path."""
    result = cs.run("bench-dynamic", bpm=BPM, afterload=HEADS, pump=pump, **KNOWN)
    assert result.ok
    return [m.metrics["stroke_volume"] / ml for m in result.members]


@pytest.mark.slow
def test_steady_state_gradient_matches_central_differences(pump):
    """d SV / d(Omega, C) of the search (shooting, implicit derivative, the scene's preset) against
    central differences of runs converged beat after beat to 1e-5 (default preset).

    About 55 s on two busy cores, 40 s of it compiling the search's function, which the
    recovery and unreachable-target tests below then reuse (run alone, the first of them pays
    the compile instead)."""
    problem = design.problem.build_problem(
        "bench-dynamic", 70.0, None, HEADS, BPM, design.DEFAULT_FREE, None, None, None, None, 0.5
    )
    evaluate = design.programs.Evaluator(problem, pump, None, "shooting")
    at = problem.base | {"omega": 4.0, "shortening": 0.4}
    z = np.repeat(problem.space.to_z(at, problem.base)[None, :], design.REFINE, axis=0)
    values, jac, ok, _ = evaluate(z)
    assert ok[0].all()
    u = 1.0 / (1.0 + np.exp(-z[0]))
    dx_dz = np.array([6.0, 0.65]) * u * (1 - u)  # the logistic map of RANGES' boxes
    gradient = jac[0, :, 0, :] / dx_dz  # (afterloads, [Omega, C]) in ml
    scene = cs.load_scene("bench-dynamic").replace(steady_tol=1e-5)
    steps = {"omega": 1e-2, "shortening": 1e-3}
    for j, (name, h) in enumerate(steps.items()):
        sv = []
        for sign in (1, -1):
            moved = {"omega": 4.0, "shortening": 0.4} | {name: at[name] + sign * h}
            result = cs.run(scene, bpm=BPM, afterload=HEADS, pump=pump, **moved)
            assert result.ok and all(m.residual <= 1e-5 for m in result.members)
            sv.append(np.array([m.metrics["stroke_volume"] / ml for m in result.members]))
        central = (sv[0] - sv[1]) / (2 * h)
        np.testing.assert_allclose(gradient[:, j], central, rtol=1e-2, err_msg=name)
    # and the values themselves agree with the converged runs to the search's accuracy
    base = cs.run(scene, bpm=BPM, afterload=HEADS, pump=pump, omega=4.0, shortening=0.4)
    sv0 = [m.metrics["stroke_volume"] / ml for m in base.members]
    np.testing.assert_allclose(values[0, :, 0], sv0, atol=0.05)


def test_search_jacobian_matches_central_differences_of_its_own_orbits(pump):
    """The search's derivatives (implicit, at the periodic orbit found by Newton shooting)
    against central differences of the orbits the same compiled programs find at z +- h: one
    batch of the search (the other tests of this module share its compile), independent runs
    being the slow test's. Held to 1 %: measured 0.14 % (SV), 0.06 % (peak force) and 0.04 %
    (mechanical work), the same at h = 1e-2, 1e-3 and 1e-4 in z, so it is the adaptive steps'
    method error (their sizes follow the design; the derivative holds them), not the
    differences'."""
    problem = design.problem.build_problem(
        "bench-dynamic", 70.0, None, HEADS, BPM, design.DEFAULT_FREE, None, None, None, None, 0.5
    )
    evaluate = design.programs.Evaluator(problem, pump, None, "shooting")
    z0 = problem.space.to_z(problem.base | {"omega": 4.0, "shortening": 0.4}, problem.base)
    h = 1e-3
    step = np.eye(2) * h
    z = np.array([z0, z0 + step[0], z0 - step[0], z0 + step[1], z0 - step[1], z0, z0, z0])
    values, jac, ok, _ = evaluate(z)
    assert ok.all()
    metrics = [design.programs.METRICS.index(k) for k in ("sv", "peak_force", "mech_work")]
    for j in range(2):
        central = (values[1 + 2 * j] - values[2 + 2 * j]) / (2 * h)
        np.testing.assert_allclose(
            jac[0][:, metrics, j], central[:, metrics], rtol=1e-2, err_msg=f"z[{j}]"
        )


@pytest.fixture(scope="module")
def recovered(pump, known_svs):
    return design.optimise(
        "bench-dynamic", target_sv=known_svs, afterload=HEADS, bpm=BPM, pump=pump
    )


def test_recovers_the_stroke_volumes_of_a_known_design(recovered, known_svs):
    """From the default design (Omega 4, C 0.4) to the SVs of Omega 3.2, C 0.45 at three heads:
    every one within 0.5 ml in the verifying run (the design need not be unique)."""
    r = recovered
    assert r.reached, r.message
    assert [t.afterload_mmHg for t in r.targets] == HEADS
    for t, sv in zip(r.targets, known_svs, strict=True):
        assert t.target_sv_ml == pytest.approx(sv)
        assert abs(t.sv_ml - sv) <= 0.5
        assert t.residual_ml == pytest.approx(t.sv_ml - sv)
        assert abs(t.search_sv_ml - t.sv_ml) < 0.1  # the search's solve agrees with run()'s
        assert t.ok and math.isfinite(t.peak_force_N) and 0 < t.efficiency < 1
    assert 0 < r.omega < 6 and 0 < r.shortening < 0.65
    assert r.iterations >= 1 and r.seconds > 0
    assert r.path[0] != r.path[-1] or len(r.path) == 1


def test_the_reported_stroke_volumes_are_those_of_run(recovered, pump):
    """Verification: the numbers reported are run()'s at the returned design."""
    r = recovered
    again = cs.run(
        "bench-dynamic",
        omega=r.omega,
        shortening=r.shortening,
        bpm=BPM,
        afterload=HEADS,
        pump=pump,
    )
    for t, m in zip(r.targets, again.members, strict=True):
        assert t.sv_ml == pytest.approx(m.metrics["stroke_volume"] / ml, rel=1e-9)
        assert t.peak_force_N == pytest.approx(m.metrics["peak_force"], rel=1e-9)


def test_a_search_for_other_targets_starts_from_the_same_grid(recovered, pump, known_svs):
    """The coarse grid's evaluations depend on the scene, the design space, the heads and the
    rates, not on the target values: a later search of another target starts from the grid
    the first evaluated (in a command, from its store across processes:
    ``program_store.stored_value``), and finds the same design for the same targets."""
    lines = []
    again = design.optimise(
        "bench-dynamic", target_sv=known_svs, afterload=HEADS, bpm=BPM, pump=pump,
        progress=lines.append,
    )  # fmt: skip
    grid = [line for line in lines if line.startswith("grid:")]
    assert len(grid) == 1 and "kept from an earlier search" in grid[0], lines
    assert (again.omega, again.shortening) == (recovered.omega, recovered.shortening)
    other = [sv + 1.0 for sv in known_svs]
    lines.clear()
    design.optimise(
        "bench-dynamic", target_sv=other, afterload=HEADS, bpm=BPM, pump=pump, max_rounds=1,
        progress=lines.append,
    )  # fmt: skip
    assert "kept from an earlier search" in next(x for x in lines if x.startswith("grid:"))


def test_unreachable_target_returns_the_closest_design_and_the_range(pump):
    r = design.optimise(
        "bench-dynamic", target_sv=250.0, afterload=HEADS, bpm=BPM, pump=pump, max_rounds=15
    )
    assert r.reached is False
    assert "not reached" in r.message
    for t in r.targets:
        lo, hi = t.reachable_sv_ml
        assert all(math.isfinite(v) for v in (t.sv_ml, t.residual_ml, lo, hi, t.peak_force_N))
        # 250 ml is beyond any ejection of a 108.6-ml cavity distended to at most ~150 ml
        assert 0 <= lo < hi < 250.0
        assert t.sv_ml == pytest.approx(hi, abs=1.0)  # the closest is the largest SV seen
        assert t.residual_ml < -20
    # the pump ejects most with the most shortening
    assert r.shortening > 0.6
    record = r.to_json()
    json.dumps(record, allow_nan=False)  # no NaN anywhere in what design.json would hold
    assert record["reached"] is False
    # an unreachable target is a flag, not a failure (every verifying run solved)
    assert r.failures == () and r.flags[0] == r.message
    assert record["flags"] == list(r.flags) and record["failures"] == []


def test_command_line_reports_an_unreachable_target_as_a_flag(tmp_path, capsys):
    """The same problem's shape as the in-process searches above (compiled once): exit 0 with
    a warning, 1 with --strict; design.json holds the flags and the exit status."""
    argv = ["--target-sv", "250", "--afterload", *map(str, HEADS), "--bpm", str(BPM)]
    argv += ["--max-rounds", "2", "--no-plot"]
    assert design.main([*argv, "--out", str(tmp_path / "a")]) == 0
    err = capsys.readouterr().err
    assert any(line.startswith("warning: not reached") for line in err.splitlines()), err
    assert "failed:" not in err
    record = json.loads((tmp_path / "a" / "design.json").read_text())
    assert record["reached"] is False and record["exit_status"] == 0
    assert record["flags"][0].startswith("not reached") and record["failures"] == []
    assert design.main([*argv, "--out", str(tmp_path / "b"), "--strict", "--quiet"]) == 1
    assert json.loads((tmp_path / "b" / "design.json").read_text())["exit_status"] == 1


@pytest.mark.parametrize(
    "kwargs, words",
    [
        (dict(target_sv=-5.0), ["target SV", "-5", "ml", "[0, inf)"]),
        (dict(target_sv=float("nan")), ["target SV", "nan", "ml"]),
        (dict(target_sv=70.0, minimize="speed"), ["minimize", "'speed'", "peak_force"]),
        (dict(target_sv=70.0, maximize="force"), ["maximize", "'force'", "efficiency"]),
        (dict(target_sv=[60.0, 70.0], afterload=HEADS), ["target_sv: 2", "afterload: 3"]),
        (dict(target_sv=70.0, afterload=200.0), ["afterload", "200", "mmHg", "[0, 150]"]),
        (dict(target_sv=70.0, bpm=0.0), ["bpm", "0", "(0, 300]"]),
        (dict(target_sv=70.0, free=("omega", "colour")), ["free", "colour", "shortening"]),
        (dict(target_sv=70.0, tol=0.0), ["tolerance", "ml"]),
        (dict(target_co=5.0, afterload=90.0, scene="lv-systemic"), ["afterload", "windkessel"]),
        (dict(), ["target_sv", "target_co"]),
    ],
)
def test_bad_input_raises_a_value_error_naming_it(kwargs, words):
    kwargs = {"scene": "bench-dynamic"} | kwargs
    with pytest.raises(ValueError) as err:
        design.optimise(kwargs.pop("scene"), **kwargs)
    for word in words:
        assert word in str(err.value), (word, str(err.value))


def test_targets_pair_up_with_afterloads_and_rates():
    p = design.problem.build_problem(
        "bench-dynamic",
        [60, 70],
        None,
        [30, 90],
        [50, 70],
        design.DEFAULT_FREE,
        None,
        None,
        None,
        None,
        0.5,
    )
    assert [(t.sv_ml, t.afterload_mmHg, t.bpm) for t in p.targets] == [
        (60, 30, 50),
        (70, 90, 70),
    ]
    one = design.problem.build_problem(
        "bench-dynamic", 70, None, None, None, design.DEFAULT_FREE, None, None, None, None, 0.5
    )
    assert [(t.sv_ml, t.afterload_mmHg, t.bpm) for t in one.targets] == [
        (70, 30, 30),
        (70, 60, 30),
        (70, 90, 30),
    ]
    lv = design.problem.build_problem(
        "lv-systemic", None, 5.0, None, [60, 80], design.DEFAULT_FREE, None, None, None, None, 0.5
    )
    assert [(t.co_l_min, t.afterload_mmHg, t.bpm) for t in lv.targets] == [
        (5.0, None, 60),
        (5.0, None, 80),
    ]


def test_design_space_maps_inside_the_ranges_and_back():
    p = design.problem.build_problem(
        "lv-systemic",
        70,
        None,
        None,
        None,
        ("omega", "shortening", "bpm", "pull_fraction", "release_fraction"),
        {"hold_fraction": 0.1},
        {"bpm": (40, 120)},
        None,
        None,
        0.5,
    )
    z = np.array([[-50.0, 50.0, 0.0, 30.0, 30.0], [0.3, -0.2, 1.0, -2.0, 0.5]])
    v = design.search.design_values(p, z)
    assert np.all((v["omega"] >= 0) & (v["omega"] <= 6))
    assert np.all((v["shortening"] >= 0) & (v["shortening"] <= 0.65))
    assert np.all((v["bpm"] > 40) & (v["bpm"] < 120))
    total = v["pull_fraction"] + v["hold_fraction"] + v["release_fraction"]
    assert np.all(total <= 1.0) and np.all(v["hold_fraction"] == 0.1)
    back = p.space.to_z({k: float(a[1]) for k, a in v.items()}, p.base)
    np.testing.assert_allclose(back, z[1], atol=1e-9)


@pytest.mark.slow  # its own compile, about 25-60 s
def test_a_freed_actuation_fraction_is_searched_and_verified(pump):
    """A fraction is a scene number, shared by a batch: the search then solves a batch of one
    per member (found broken by hand once, 2026-12-02). The verifying run()'s SV is the answer."""
    r = design.optimise(
        "bench-dynamic",
        target_sv=70.0,
        afterload=90.0,
        bpm=60.0,
        free=("omega", "shortening", "pull_fraction"),
        max_rounds=4,
        pump=pump,
    )
    assert r.reached, r.message
    assert 0 < r.design["pull_fraction"] < 1 and r.design["release_fraction"] == 0.5
    check = cs.run(
        cs.load_scene("bench-dynamic").replace(pull_fraction=r.design["pull_fraction"]),
        omega=r.omega,
        shortening=r.shortening,
        bpm=60,
        afterload=[90],
        pump=pump,
    )
    (member,) = check.members
    assert member.metrics["stroke_volume"] / ml == pytest.approx(r.targets[0].sv_ml, abs=1e-9)
    assert abs(r.targets[0].sv_ml - 70.0) <= 0.5


def test_the_optimiser_is_an_optax_chain_and_steps_by_gauss_newton():
    """One residual, two variables: the step is the least-norm one that zeroes the
    linearised residual (no objective, a radius that does not bind)."""
    import jax.numpy as jnp

    opt = design.design_optimiser()
    z = jnp.zeros(2)
    state = opt.init(z)
    residual, jacobian = jnp.array([3.0]), jnp.array([[1.0, 2.0]])
    step, _ = opt.update(
        jnp.zeros(2),
        state,
        z,
        residual=residual,
        jacobian=jacobian,
        mask=jnp.ones(2),
        radius=10.0,
    )
    np.testing.assert_allclose(step, [-0.6, -1.2], atol=1e-12)
    np.testing.assert_allclose(jacobian @ step + residual, 0.0, atol=1e-12)
    clipped, _ = opt.update(
        jnp.zeros(2),
        state,
        z,
        residual=residual,
        jacobian=jacobian,
        mask=jnp.ones(2),
        radius=0.1,
    )
    assert float(jnp.linalg.norm(clipped)) == pytest.approx(0.1)


# ------------------------------------------------------------------------------ command line


def launch(*args, cwd=REPO):
    return subprocess.Popen(
        [sys.executable, "-m", "cardiosoft.design", *map(str, args)],
        cwd=cwd,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def finish(proc, timeout=600):
    out, err = proc.communicate(timeout=timeout)
    return subprocess.CompletedProcess(proc.args, proc.returncode, out, err)


BAD_CLI = {
    "negative": (["--target-sv", "-5"], ["target SV", "-5", "ml", "[0, inf)"]),
    "nan": (["--target-sv", "nan"], ["target SV", "nan", "ml"]),
    "objective": (["--target-sv", "70", "--minimize", "speed"], ["minimize", "speed"]),
    "counts": (
        ["--target-sv", "60", "70", "--afterload", "30", "60", "90"],
        ["--target-sv: 2", "--afterload: 3"],
    ),
    "word": (["--target-sv", "seventy"], ["--target-sv", "seventy"]),
}


@pytest.mark.parametrize("name", list(BAD_CLI))
def test_command_line_bad_input_exits_2_with_one_line_and_writes_nothing(name, tmp_path, capsys):
    """``main()`` in this process (the checks come before any solve; ``python -m`` runs the
    same function, see the runpy test below)."""
    args, words = BAD_CLI[name]
    out = tmp_path / "out"
    try:
        status = design.main([*args, "--out", str(out)])
    except SystemExit as exit:  # argparse's own errors
        status = exit.code
    captured = capsys.readouterr()
    assert status == 2, captured.err
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1, captured.err
    for word in words:
        assert word in lines[0], (word, lines[0])
    assert captured.out == ""
    assert not out.exists()


def test_command_line_runs_without_the_runpy_warning(tmp_path):
    out = subprocess.run(
        [sys.executable, "-W", "error::RuntimeWarning", "-m", "cardiosoft.design", "--help"],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=tmp_path,
    )
    assert out.returncode == 0, out.stderr
    assert "usage: python -m cardiosoft.design" in out.stdout
    assert "--target-sv" in out.stdout and "--pareto" in out.stdout


@pytest.mark.slow
def test_design_json_agrees_with_an_independent_simulate_run(tmp_path):
    """``python -m cardiosoft.design --out`` then ``python -m cardiosoft.simulate`` of the
    design it names: the stroke volume written is the simulator's. Two fresh processes, each
    compiling. The design search finds its orbits beat after beat (``--steady beats``), which
    compiles in about two thirds of the time of the default Newton shooting; the shooting
    search is tested in this process above, and what is checked here (the file against the
    simulator) does not depend on it. A design that drives the pump past the surrogate's fitted
    range is flagged by both tools, a warning that leaves the exit status 0."""
    out = tmp_path / "design"
    result = finish(
        launch("--target-sv", 70, "--afterload", 90, "--bpm", 60, "--steady", "beats", "--out", out)
    )
    assert result.returncode == 0, result.stderr
    assert sorted(p.name for p in out.iterdir()) == ["design.json", "design.png"]
    record = json.loads((out / "design.json").read_text())
    assert {"omega", "shortening", "reached", "iterations", "seconds", "targets"} <= set(record)
    assert record["reached"] is True
    (target,) = record["targets"]
    assert target["afterload_mmHg"] == 90 and target["target_sv_ml"] == 70
    assert abs(target["sv_ml"] - 70) <= 0.5
    assert f"{record['omega']:.4f}" in result.stdout and "70.00" in result.stdout
    sim = tmp_path / "simulate"
    check = subprocess.run(
        [
            sys.executable,
            "-m",
            "cardiosoft.simulate",
            "--omega",
            repr(record["omega"]),
            "--shortening",
            repr(record["shortening"]),
            "--bpm",
            "60",
            "--afterload",
            "90",
            "--no-plot",
            "--out",
            str(sim),
            "--quiet",
        ],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert check.returncode == 0, check.stderr
    assert [
        f.split(": ", 1)[1] for f in json.loads((sim / "summary.json").read_text())["flags"]
    ] == target["flags"]
    (simulated,) = json.loads((sim / "summary.json").read_text())["records"]
    assert simulated["dynamic_sv_ml"] == pytest.approx(target["sv_ml"], abs=1e-6)
    assert simulated["peak_force_N"] == pytest.approx(target["peak_force_N"], abs=1e-6)
    assert abs(simulated["dynamic_sv_ml"] - 70) <= 0.5
