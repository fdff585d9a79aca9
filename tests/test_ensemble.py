"""Ensembles through the batch solve (cardiosoft.ensemble, cardiosoft.batch): a pump whose
fitted leaves carry a leading axis of draws is one more batch axis (issue #24).

Independent source: the same draws solved one by one.
"""

import dataclasses

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

from cardiosoft.batch import default_config, ensemble_size, solve_beats, solve_static
from cardiosoft.pump import load
from cardiosoft.scene import load_scene
from cardiosoft.units import mmHg

HEADS = np.array([30.0, 90.0]) * mmHg


def _ensemble(pump, shifts):
    """An ensemble of ``pump`` whose chamber elastance is shifted by ``shifts`` (log)."""
    return eqx.tree_at(
        lambda p: p.log_chamber_elastance, pump, pump.log_chamber_elastance + jnp.asarray(shifts)
    )


def _single(pump, ens, s):
    return eqx.tree_at(lambda p: p.log_chamber_elastance, pump, ens.log_chamber_elastance[s])


def test_ensemble_static_strokes_are_one_batch_axis_over_the_draws():
    """Each (draw, member) of one ensemble of quasi-static strokes equals that draw alone
    (the same Newton steps on each: to round-off, 1e-9 relative)."""
    pump, scene = load(), load_scene("bench-dynamic")
    ens = _ensemble(pump, [0.0, 0.05, -0.05])
    assert ensemble_size(ens) == 3 and ensemble_size(pump) is None
    diameters = np.array([0.018, 0.03, 0.045])
    out = solve_static(scene, afterload=HEADS, pump=ens,
                       scene_draws={"column_diameter": diameters})
    assert out.stroke_volume.shape == (3, 2)
    for s in range(3):
        alone = solve_static(scene.replace(column_diameter=diameters[s]), afterload=HEADS,
                             pump=_single(pump, ens, s))
        np.testing.assert_allclose(out.stroke_volume[s], alone.stroke_volume, rtol=1e-9)
        np.testing.assert_allclose(out.peak_force[s], alone.peak_force, rtol=1e-9)


def test_ensemble_solve_is_one_batch_axis_over_the_draws():
    """Each (draw, member) of one ensemble solve equals that draw solved alone. Tolerance: the
    two paths take their own adaptive steps, so they agree to the solver's tolerance, not to
    round-off."""
    pump, scene = load(), load_scene("bench-dynamic")
    ens, tubes = _ensemble(pump, [0.0, 0.05, -0.05]), np.array([0.11, 0.12, 0.13])
    out = solve_beats(
        scene, afterload=HEADS, beats=2, save="metrics", pump=ens,
        scene_draws={"tube_length": tubes},
    )
    assert out.metrics.stroke_volume.shape == (3, 2)
    rtol = default_config(scene).rtol
    for s in range(3):
        alone = solve_beats(scene.replace(tube_length=tubes[s]), afterload=HEADS, beats=2,
                            save="metrics", pump=_single(pump, ens, s))
        np.testing.assert_allclose(out.metrics.stroke_volume[s], alone.metrics.stroke_volume,
                                   rtol=rtol)
        np.testing.assert_allclose(out.metrics.peak_force[s], alone.metrics.peak_force, rtol=rtol)


def test_ensemble_refuses_draws_of_unequal_number():
    ens = _ensemble(load(), [0.0, 0.1])
    with pytest.raises(ValueError, match="disagree in number"):
        ensemble_size(ens, {"tube_length": np.ones(3)})
    with pytest.raises(ValueError, match="not a scene number"):
        ensemble_size(ens, {"omega": np.ones(2)})


def test_a_failed_draw_is_counted_per_member():
    """A draw whose solve runs out of steps (a 0.2-mm tube: stiff for an explicit solver at a
    bounded step count) is reported failed at each member, the others not."""
    scene = load_scene("bench-dynamic")
    config = dataclasses.replace(default_config(scene), max_steps=400)
    out = solve_beats(
        scene, afterload=HEADS, beats=2, save="metrics", config=config,
        scene_draws={"tube_diameter": np.array([20e-3, 0.2e-3, 20e-3])},
    )
    ok = np.asarray(out.succeeded)
    assert ok.shape == (3, 2)
    assert not ok[1].any() and ok[[0, 2]].all()
    assert "solver failed" in out.message((1, 0))
