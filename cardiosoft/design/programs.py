"""The search's compiled programs: the periodic orbits of a batch of candidates, then their
implicit derivatives.

Each evaluation of a batch of candidates is two compiled programs: the periodic orbits without
derivatives (:func:`periodic_orbits`: ``steady="shooting"``, Newton shooting on the one-beat
map, or ``"beats"``, beat after beat from rest; :func:`cardiosoft.solve_beats`), then one beat
from each orbit's start by :func:`cardiosoft.solve_orbit`, whose derivative is the periodic
steady state's by the implicit function theorem (:func:`orbit_derivatives`). Each program is
about half the size of the shooting solve differentiated whole, and :class:`Evaluator` compiles
the two at once on two threads (XLA compiles without Python's lock), so the second is traced
while the first compiles (#13).
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import time
from typing import ClassVar

import jax
import jax.numpy as jnp
import numpy as np

from cardiosoft.batch import default_config, solve_beats, solve_orbit, split_scene
from cardiosoft.design.problem import FRACTIONS, Problem
from cardiosoft.program_store import stored_lowering
from cardiosoft.solve import PRESETS
from cardiosoft.units import ml, mmHg

__all__ = [
    "COMPILER",
    "METRICS",
    "ORBIT_DERIVATIVES",
    "PERIODIC_ORBITS",
    "Evaluator",
    "member_inputs",
    "member_solver",
    "orbit_derivatives",
    "periodic_orbits",
]

METRICS = ("sv", "co", "peak_force", "mech_work", "efficiency")
"""What one evaluation returns per target, in ml, l/min, N, J and -."""


def member_solver(structure, numbers, pump, config, space, steady):
    """``solve(x, bpm, head, start) -> (metrics (m, 5), (ok (m,), beats (m,), y0))`` of m
    members: design values ``x``, rates, heads (None for a Windkessel) and, with
    ``steady="orbit"``, orbit starts (:func:`cardiosoft.batch.solve_orbit`). The orbits
    themselves (``steady`` "shooting" or "beats") come without metrics (None)."""
    fractions_free = any(f in space.names for f in FRACTIONS)

    def solve(scene, x, bpm, head, start):
        common = dict(
            omega=x["omega"],
            shortening=x["shortening"],
            bpm=bpm,
            afterload=head,
            pump=pump,
            config=config,
        )
        if steady != "orbit":  # no sampled beat: the orbit's start is all it is for
            out = solve_beats(scene, steady=steady, save="state", **common)
            return None, (out.succeeded & out.steady, out.beats, out.y0)
        out = solve_orbit(scene, start, save="metrics", **common)
        m = out.metrics
        values = jnp.stack(
            [
                m.stroke_volume / ml,
                m.cardiac_output * (60.0 / (1000.0 * ml)),
                m.peak_force,
                m.mech_work,
                m.efficiency,
            ],
            axis=-1,
        )
        ok = out.succeeded & out.steady & jnp.all(jnp.isfinite(values), axis=-1)
        return values, (ok, out.beats, out.y0)

    def members(x, bpm, head, start):
        if not fractions_free:  # every member field of the batch solve: one batch
            return solve(dataclasses.replace(structure, **numbers), x, bpm, head, start)

        # the fractions are scene numbers, shared by a batch: a batch of one per member
        def one(x_m, bpm_m, head_m, start_m):
            scene = dataclasses.replace(structure, **(numbers | {f: x_m[f] for f in FRACTIONS}))
            one_head = None if head_m is None else head_m[None]
            one_start = jax.tree_util.tree_map(lambda a: a[None], start_m)
            out = solve(scene, x_m, bpm_m[None], one_head, one_start)
            return jax.tree_util.tree_map(lambda a: a[0], out)

        (size,) = jnp.broadcast_shapes(*(jnp.shape(v) for v in (*x.values(), bpm)))
        x = {name: jnp.broadcast_to(v, (size,)) for name, v in x.items()}
        return jax.vmap(one)(x, jnp.broadcast_to(bpm, (size,)), head, start)

    return members


def member_inputs(z, base, heads, rates, space, target):
    x = space.values(z, base)
    bpm = x["bpm"] if "bpm" in space.names else rates[target]
    return x, bpm, None if heads is None else heads[target]


def orbit_derivatives(z, base, heads, rates, numbers, pump, config, starts, *, structure, space):
    """Metrics (R, K, 5) of candidates ``z`` (R, d) at the K targets, their derivatives with
    respect to z (R, K, 5, d), and ok (R, K): one beat from ``starts``, the orbit starts of
    the R x K members (:func:`periodic_orbits`), differentiated as the orbits
    (:func:`cardiosoft.solve_orbit`).

    One forward-mode pass over one batch: each candidate is repeated once per free variable
    (and per target), every copy moved along its own variable by the same tangent, so a
    single ``jax.jvp`` of one vmapped solve gives every column of every Jacobian. That costs
    d primal solves per candidate instead of one, and saves a vmap over the tangents, which
    would batch every while loop of the solve once more: measured, the trace and the compile
    take about half as long.
    """
    n, d = z.shape
    k = rates.shape[0]
    candidate = jnp.repeat(jnp.arange(n), d * k)
    direction = jnp.tile(jnp.repeat(jnp.arange(d), k), n)
    target = jnp.tile(jnp.arange(k), n * d)
    z_m = z[candidate]
    unit = jnp.eye(d, dtype=z.dtype)[direction]
    solve = member_solver(structure, numbers, pump, config, space, "orbit")
    start = jax.tree_util.tree_map(lambda a: a[candidate * k + target], starts)

    def members(t):
        values, (ok, _, _) = solve(
            *member_inputs(z_m + t[:, None] * unit, base, heads, rates, space, target), start
        )
        return values, ok

    zero = jnp.zeros(n * d * k, z.dtype)
    values, tangents, ok = jax.jvp(members, (zero,), (jnp.ones_like(zero),), has_aux=True)
    ok = ok & jnp.all(jnp.isfinite(tangents), axis=-1)
    values = values.reshape(n, d, k, -1)[:, 0]
    jac = jnp.moveaxis(tangents.reshape(n, d, k, -1), 1, -1)
    return values, jac, ok.reshape(n, d, k).all(axis=1)


def periodic_orbits(z, base, heads, rates, numbers, pump, config, *, structure, space, steady):
    """(ok (R x K,), beats, y0) of the R x K members of candidates ``z`` (R, d) at the K
    targets: their periodic orbits (``steady``: "shooting" or "beats"), without derivatives
    (:func:`orbit_derivatives` differentiates them)."""
    n, k = z.shape[0], rates.shape[0]
    candidate, target = jnp.repeat(jnp.arange(n), k), jnp.tile(jnp.arange(k), n)
    solve = member_solver(structure, numbers, pump, config, space, steady)
    _, (ok, beats, y0) = solve(
        *member_inputs(z[candidate], base, heads, rates, space, target), None
    )
    return ok, beats, y0


ORBIT_DERIVATIVES = jax.jit(orbit_derivatives, static_argnames=("structure", "space"))
PERIODIC_ORBITS = jax.jit(periodic_orbits, static_argnames=("structure", "space", "steady"))


class Evaluator:
    """The search's compiled programs for a problem's shape, and their timings.

    A call is two programs: the orbits without derivatives (:func:`periodic_orbits`), then their
    implicit derivatives at those orbits (:func:`orbit_derivatives`). Each is about half the size of
    the shooting solve differentiated whole, and they compile at once, on two threads: XLA
    compiles without Python's lock, so the second is traced while the first compiles (#13)."""

    _compiled: ClassVar[dict] = {}  # shared by every search of the process: no recompile
    _pending: ClassVar[dict] = {}  # traced, compiling on a thread

    def __init__(self, problem: Problem, pump, accuracy: str | None, steady: str):
        scene = problem.scene
        if accuracy is not None and accuracy not in PRESETS:
            raise ValueError(f"accuracy = {accuracy!r}: allowed {', '.join(PRESETS)}")
        config = default_config(scene if accuracy is None else scene.replace(accuracy=accuracy))
        self.structure, self.numbers = split_scene(scene, keep_steady=True)
        self.pump, self.config, self.space, self.steady = pump, config, problem.space, steady
        ftype = jnp.result_type(float)
        self.base = {k: jnp.asarray(v, ftype) for k, v in problem.base.items()}
        heads = problem.heads_mmHg
        self.heads = None if heads is None else jnp.asarray(heads, ftype) * mmHg
        rates = [problem.base["bpm"] if t.bpm is None else t.bpm for t in problem.targets]
        self.rates = jnp.asarray(rates, ftype)
        self.compile_s = 0.0  # trace, lower and compile, until the programs are ready
        self.trace_s = 0.0  # trace and lower
        self.calls = 0
        self.call_s: list[float] = []

    def _args(self, z):
        z = jnp.asarray(z, jnp.result_type(float))
        args = (z, self.base, self.heads, self.rates, self.numbers, self.pump, self.config)
        leaves, treedef = jax.tree_util.tree_flatten(args)
        key = (
            self.structure,
            self.space,
            self.steady,
            treedef,
            tuple((np.shape(a), jnp.result_type(a)) for a in leaves),
        )
        return args, key

    def compiled(self, z: np.ndarray) -> bool:
        """Whether this process has the programs for the shape of ``z`` already."""
        return self._args(z)[1] in self._compiled

    def trace(self, z: np.ndarray) -> None:
        """Trace and lower for the shape of ``z`` now, each program then compiling on a thread
        of its own while the next is traced (tracing holds Python's lock, XLA does not)."""
        args, key = self._args(z)
        if key in self._compiled or key in self._pending:
            return
        start = time.perf_counter()
        static = dict(structure=self.structure, space=self.space)
        # a command's process loads the programs it stored before (cardiosoft.program_store)
        orbits = stored_lowering(
            periodic_orbits, *args, **static, steady=self.steady
        ) or PERIODIC_ORBITS.lower(*args, **static, steady=self.steady)
        compiling = [COMPILER.submit(orbits.compile)]
        starts = orbits.out_info[2]  # the shapes of the orbit starts
        derivatives = stored_lowering(
            orbit_derivatives, *args, starts, **static
        ) or ORBIT_DERIVATIVES.lower(*args, starts, **static)
        compiling.append(COMPILER.submit(derivatives.compile))
        self._pending[key] = (start, compiling)
        self.trace_s += time.perf_counter() - start

    def __call__(self, z: np.ndarray):
        """(values (R, K, 5), jac (R, K, 5, d), ok (R, K), beats (R, K)) as numpy."""
        self.trace(z)
        args, key = self._args(z)
        if key not in self._compiled:
            begin, compiling = self._pending.pop(key)
            self._compiled[key] = [c.result() for c in compiling]
            self.compile_s += time.perf_counter() - begin
        start = time.perf_counter()
        orbits, derivative = self._compiled[key]
        ok_orbit, beats, y0 = orbits(*args)
        values, jac, ok = derivative(*args, y0)
        ok = np.asarray(ok) & np.asarray(ok_orbit).reshape(ok.shape)
        values, jac = np.asarray(values), np.asarray(jac)
        self.call_s.append(time.perf_counter() - start)
        self.calls += 1
        return values, jac, ok, np.asarray(beats).reshape(ok.shape)


COMPILER = concurrent.futures.ThreadPoolExecutor(max_workers=2, thread_name_prefix="compile")
"""XLA compiles the search's two programs here, each on a thread of its own."""
