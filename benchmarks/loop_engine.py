"""The closed loop's two engines side by side: its equations written out, and the same
equations as a network of blocks solved in their structural order (issue #40).

    python benchmarks/loop_engine.py [--scene heart --scene tah]   # ~2 min on 2 cores

For each scene and engine (:attr:`cardiosoft.network.closed_loop.ClosedLoop.engine`), from a
fresh process with the persistent compile cache off:

- ``equations``: the size of the vector field's program (jaxpr equations), which sets the
  tracing and compile time;
- ``order``: the time to find the network's solving order (once a process);
- ``first``: the first ``solve_loop`` to the periodic steady state (tracing, compiling, running);
- ``again``: the same solve at another rate (compiled: the run alone);
- and, from the reference preset (12 beats), the largest relative difference of any metric
  between the engines.
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
from cardiosoft.network.loop_batch import solve_loop
from cardiosoft.network.loop_scene import loop_circuit
from cardiosoft.pump import load

name, engine = sys.argv[1], sys.argv[2]
scene = cs.load_scene(name)
start = time.perf_counter()
if engine == "network":
    from cardiosoft.network.closed_loop import loop_order
    loop_order()
order = time.perf_counter() - start
loop = loop_circuit(scene, load(scene.pump) if scene.pumps else None, engine)
y = loop.init()
equations = len(jax.make_jaxpr(lambda y: loop(0.1, y))(y).jaxpr.eqns)
start = time.perf_counter()
jax.block_until_ready(solve_loop(scene, save="metrics", engine=engine).metrics)
first = time.perf_counter() - start
start = time.perf_counter()
jax.block_until_ready(solve_loop(scene, save="metrics", bpm=80.0, engine=engine).metrics)
again = time.perf_counter() - start
print(json.dumps(dict(equations=equations, order=order, first=first, again=again)))
"""

AGREEMENT = r"""
import dataclasses, json, sys
import diffrax, jax, numpy as np
jax.config.update("jax_enable_x64", True)
import cardiosoft as cs
from cardiosoft.network.loop_batch import solve_loop
from cardiosoft.solve import preset

scene = cs.load_scene(sys.argv[1])
config = dataclasses.replace(preset("reference"), adjoint=diffrax.ForwardMode())
runs = []
for engine in ("direct", "network"):
    m = solve_loop(scene, beats=12, save="metrics", config=config, engine=engine).metrics
    runs.append({f"{s}.{f.name}": float(getattr(getattr(m, s), f.name)[0])
                 for s in ("left", "right") for f in dataclasses.fields(getattr(m, s))})
worst = max((abs(runs[1][k] - v) / abs(v) for k, v in runs[0].items() if np.isfinite(v)))
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
    parser.add_argument("--scene", action="append", help="closed-loop scenes (heart, tah)")
    scenes = parser.parse_args().scene or ["heart", "tah"]
    print(f"{'scene':8s} {'engine':8s} {'equations':>9s} {'order s':>8s} {'first s':>8s} "
          f"{'again s':>8s}")  # fmt: skip
    for name in scenes:
        rows = {}
        for engine in ("direct", "network"):
            r = rows[engine] = _child(CHILD, name, engine)
            print(
                f"{name:8s} {engine:8s} {r['equations']:9d} {r['order']:8.2f} "
                f"{r['first']:8.2f} {r['again']:8.3f}"
            )
        d, n = rows["direct"], rows["network"]
        print(
            f"{name:8s} network / direct: equations x{n['equations'] / d['equations']:.1f}, "
            f"first solve x{(n['order'] + n['first']) / d['first']:.2f} (order included), "
            f"again x{n['again'] / d['again']:.2f}; largest metric difference at the "
            f"reference preset: {_child(AGREEMENT, name)['worst']:.1e}"
        )


if __name__ == "__main__":
    main()
