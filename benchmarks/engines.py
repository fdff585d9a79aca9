"""A scene's two engines side by side: its equations written out, and the same equations as a
network of blocks solved in their structural order (issue #40).

    python benchmarks/engines.py [--scene bench-dynamic --scene heart ...]   # ~6 min, 2 cores

For each scene and engine (``engine=`` of :func:`cardiosoft.solve_beats`: an open loop's
:class:`~cardiosoft.circuit.PumpCircuit` or :class:`~cardiosoft.network.bench.BenchNetwork`, a
closed loop's :attr:`~cardiosoft.network.closed_loop.ClosedLoop.engine`), from a fresh process
with the persistent compile cache off:

- ``equations``: the size of the vector field's program (jaxpr equations), which sets the
  tracing and compile time;
- ``order``: the time to find the network's solving order (once a process);
- ``first``: the first solve to the periodic steady state (tracing, compiling, running);
- ``again``: the same solve at another rate (compiled: the run alone);
- and, from the reference preset (12 beats; the open loops' 3), the largest relative difference
  of any metric between the engines.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

CHILD = r"""
import json, sys, time
import jax
jax.config.update("jax_enable_x64", True)
import cardiosoft as cs
from cardiosoft.pump import load
from cardiosoft.scene import Scene

name, engine = sys.argv[1], sys.argv[2]
scene = cs.load_scene(name)
pump = load(scene.pump) if getattr(scene, "pump", None) else None
start = time.perf_counter()
if isinstance(scene, Scene):  # the benchmark, not the package, tells the kinds apart
    from cardiosoft.batch import scene_circuit
    circuit = scene_circuit(scene, pump, engine=engine)
    y = circuit.init()
    start = time.perf_counter()
    if engine == "network":
        circuit.network(y)  # finds the order
else:
    from cardiosoft.network.closed_loop import loop_order
    from cardiosoft.network.loop_scene import loop_circuit
    if engine == "network":
        loop_order()
    circuit = loop_circuit(scene, pump, engine)
    y = circuit.init()
order = time.perf_counter() - start
equations = len(jax.make_jaxpr(lambda y: circuit(0.1, y))(y).jaxpr.eqns)
start = time.perf_counter()
jax.block_until_ready(cs.solve_beats(scene, save="metrics", engine=engine).metrics)
first = time.perf_counter() - start
start = time.perf_counter()
jax.block_until_ready(cs.solve_beats(scene, save="metrics", bpm=80.0, engine=engine).metrics)
again = time.perf_counter() - start
print(json.dumps(dict(equations=equations, order=order, first=first, again=again)))
"""

AGREEMENT = r"""
import dataclasses, json, sys
import diffrax, jax, numpy as np
jax.config.update("jax_enable_x64", True)
import cardiosoft as cs
from cardiosoft.scene import Scene
from cardiosoft.solve import preset

scene = cs.load_scene(sys.argv[1])
beats = 3 if isinstance(scene, Scene) else 12
config = dataclasses.replace(preset("reference"), adjoint=diffrax.ForwardMode())
runs = [
    cs.solve_beats(scene, beats=beats, save="metrics", config=config, engine=engine).metrics
    for engine in ("direct", "network")
]
worst = 0.0
for a, b in zip(*map(jax.tree.leaves, runs), strict=True):
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    ok = np.isfinite(a) & (a != 0)
    if ok.any():
        worst = max(worst, float(np.max(np.abs(b[ok] - a[ok]) / np.abs(a[ok]))))
print(json.dumps(dict(worst=worst)))
"""


def _child(code, *args):
    env = os.environ | {"JAX_ENABLE_COMPILATION_CACHE": "false"}
    out = subprocess.run(
        [sys.executable, "-c", code, *args], env=env, capture_output=True, text=True, check=True
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", action="append", help="dynamic scenes (default: all four)")
    scenes = parser.parse_args().scene or ["bench-dynamic", "lv-systemic", "heart", "tah"]
    print(f"{'scene':13s} {'engine':8s} {'equations':>9s} {'order s':>8s} {'first s':>8s} "
          f"{'again s':>8s}")  # fmt: skip
    for name in scenes:
        rows = {}
        for engine in ("direct", "network"):
            r = rows[engine] = _child(CHILD, name, engine)
            print(
                f"{name:13s} {engine:8s} {r['equations']:9d} {r['order']:8.2f} "
                f"{r['first']:8.2f} {r['again']:8.3f}"
            )
        d, n = rows["direct"], rows["network"]
        print(
            f"{name:13s} network / direct: equations x{n['equations'] / d['equations']:.1f}, "
            f"first solve x{(n['order'] + n['first']) / d['first']:.2f} (order included), "
            f"again x{n['again'] / d['again']:.2f}; largest metric difference at the "
            f"reference preset: {_child(AGREEMENT, name)['worst']:.1e}"
        )


if __name__ == "__main__":
    main()
