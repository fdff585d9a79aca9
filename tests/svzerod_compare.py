"""cardiosoft's network against svZeroDSolver at refined steps: the comparison that
``tests/test_network.py`` (the vendored cases) and ``tests/test_network_random.py`` (random
networks) share.

svZeroDSolver steps a fixed-step second-order generalized-alpha scheme, so its answer depends on
its step. :func:`check_agreement` runs ``svzerod`` at three refinements of the case's step
(``(1, 4, 16)`` unless told otherwise), measures the observed order p from the three (from the
largest differences, and at each sample where its own is lower), and estimates the error left
at the finest as ``|y_4 - y_16| / (4^p - 1)`` (Richardson, p clipped to [1, 3]). Our adaptive
solve (preset "reference", rtol 1e-10) must lie within twice that estimate (plus our own error)
of the finest ``svzerod`` answer at every sample, plus 1e-7 of each variable's range.
"""

import numpy as np

from cardiosoft import network


def _compared(var: str, ours, steep: bool):
    """The samples where a variable means the same in both solvers, or is not at the mercy of
    a switch between two samples. A closed valve of the combined heart block carries no flow
    here (0); svzerod reports its inductor's drift there, which no equation uses (its valve
    factor is 0). Its valve flows are compared where the valve is open here, at the sample and
    both neighbours. ``steep``: the case's valves are steps (tanh of steepness 1e4 per mmHg)."""
    if var.startswith("Q_") and var.endswith(":CLH"):
        is_open = ours != 0
        return is_open & np.roll(is_open, 1) & np.roll(is_open, -1)
    if var.startswith("valve_status:") and steep:
        # a tanh valve of steepness 1e4 per mmHg: its status is a step in the pressure
        # difference, flipped by 1e-4 mmHg next to a switch; the pressures are compared
        return np.zeros(ours.shape, dtype=bool)
    return np.ones(ours.shape, dtype=bool)


def check_agreement(
    config: dict,
    name: str,
    refinements=(1, 4, 16),
    steep: bool = False,
    floor: float = 0.0,
    peer=network.run_svzerod,
) -> network.Traces:
    """Assert that cardiosoft's solve of the svZeroDSolver model ``config`` agrees with
    ``svzerod``'s at every output sample, to the tolerance its refinements give (the module's
    docstring); ``name`` labels the messages. ``floor``: an absolute allowance added to every
    tolerance, in the model's units (svzerod's Newton stops at an absolute residual, which on a
    constant near zero, a PRESSURE outlet's 1e-5 say, is more than 1e-7 of its range).
    ``peer(config, refine)``: svZeroDSolver's answer at ``refine`` times its points a beat
    (:func:`stepped_as_svzerod` where ``svzerod`` cannot run the case). Returns our traces
    (preset "reference")."""
    model = network.read(config)
    traces = network.simulate(model, "reference")
    assert traces.solved and traces.steady_start in (True, None)
    # our own error, bounded by the same program at a 100 times looser rtol
    looser = network.simulate(model, "reference", rtol=1e-8).values
    ratio = refinements[1] / refinements[0]
    coarse, middle, fine = (peer(config, r) for r in refinements)
    assert set(traces.values) == set(fine), "svZeroDSolver's variable names"
    sim = config["simulation_parameters"]
    # svzerod reports a start from initial_condition as given (t = 0, when output); here the
    # nodes there are the ones consistent with the states
    start = 0 if sim.get("steady_initial", True) else 1
    tolerances = {}  # of the variables compared at every sample
    for var, ours in traces.values.items():
        at = _compared(var, ours, steep)
        at[:start] = False
        if var.startswith("ydot:") and sim.get("output_all_cycles"):
            # svzerod's rates at t = 0 are the ones it starts from (its steady start-up's,
            # 0 for a flow table's), not the model's there
            at[0] = False
        if not at.any():
            continue
        ref = fine[var][at]
        scale = np.ptp(fine[var]) + np.max(np.abs(fine[var])) * 1e-3 + 1e-300
        # Richardson: the order p from the largest differences, and at each sample its own
        # where that is lower (svzerod converges at first order just after a valve switches,
        # at the decomposed heart's first samples after one): what is left there is larger
        e1, e2 = np.abs(coarse[var] - middle[var])[at], np.abs(middle[var][at] - ref)
        order = 2.0
        if e2.max() > 1e-9 * scale:
            order = np.clip(np.log(e1.max() / e2.max()) / np.log(ratio), 1.0, 3.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            local = np.clip(np.log(e1 / e2) / np.log(ratio), 1.0, 3.0)
        local = np.where((e2 > 1e-9 * scale) & np.isfinite(local), local, order)
        left = np.maximum(
            e2.max() / (ratio**order - 1), e2 / (ratio ** np.minimum(local, order) - 1)
        )
        own = np.max(np.abs(looser[var] - ours)[at])
        tolerance = 2 * (left + own) + 1e-7 * scale + floor
        error = np.abs(ours[at] - ref)
        if at.all():
            tolerances[var] = tolerance
        worst = int(np.argmax(error - tolerance))
        assert np.all(error <= tolerance), (
            f"{name} {var}: {error[worst]:.3g} > {tolerance[worst]:.3g} at sample {worst} "
            f"(svzerod's error left {left[worst]:.3g}, order {order:.2f} and {local[worst]:.2f} "
            f"there; ours {own:.3g})"
        )
    if sim.get("output_mean_only"):
        _check_means(config, name, traces, coarse, fine, tolerances)
    return traces


def stepped_as_svzerod(config: dict, refine: int = 1) -> dict:
    """svZeroDSolver's scheme at ``refine`` times the model's points a beat, every
    ``refine``-th sample kept, as :func:`cardiosoft.network.run_svzerod` gives it: the stepping
    of :func:`cardiosoft.network.step_as_svzerod`, held to svZeroDSolver's own stored result at
    the model's step (``tests/test_network_gen_alpha.py``)."""
    import json

    config = json.loads(json.dumps(config))
    sim = config["simulation_parameters"]
    sim["number_of_time_pts_per_cardiac_cycle"] = (
        sim["number_of_time_pts_per_cardiac_cycle"] - 1
    ) * refine + 1
    values = network.step_as_svzerod(network.read(config)).values
    return {k: np.asarray(v)[::refine] for k, v in values.items()}


def _check_means(config, name, traces, coarse, fine, tolerances) -> None:
    """``output_mean_only``: svzerod's means are its output samples' arithmetic means (both
    ends of a beat, every beat with ``output_all_cycles``), which our ``Traces.means`` must
    match; ours lie within the mean of the samples' tolerances of the converged samples' mean
    (a mean of differences each within its tolerance)."""
    import json

    import svzerod

    config = json.loads(json.dumps(config))  # the case as it stands, read by variable
    config["simulation_parameters"]["output_variable_based"] = True
    frame = svzerod.simulate(config)
    columns = [c for c in ("y", "ydot") if c in frame]
    for var, group in frame.groupby("name"):
        for column in columns:
            own = group[column].to_numpy()
            key = var if column == "y" else f"ydot:{var}"
            assert own.shape == (1,), f"{name}: svzerod writes one mean of {key}"
            np.testing.assert_allclose(own[0], np.mean(coarse[key]), rtol=1e-12, atol=1e-300)
    means = traces.means()
    assert tolerances, f"{name}: no variable compared at every sample"
    for var, tolerance in tolerances.items():
        error = abs(means[var] - np.mean(fine[var]))
        assert error <= np.mean(tolerance), (
            f"{name} mean of {var}: {error:.3g} > {np.mean(tolerance):.3g}"
        )
