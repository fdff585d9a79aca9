"""Programs that outlive a process (issue #41): a jitted solve is exported once with
``jax.export`` (its traced StableHLO) and stored beside the compile cache, so that a later
process deserialises it instead of tracing it. JAX's compile cache then gives the executable.

JAX traces a program again in every process: of a warm ``simulate --bpm 60`` (8.4 s on a busy
2-core machine) most was tracing; loading the stored programs instead takes it to 3.1 s, and
the README's design question from 21 s to 5.5 s (``benchmarks/startup.py``). A cold process
traces, exports and stores (0.5 s more than tracing alone).

- :func:`stored_call` runs an ``eqx.filter_jit`` function through its stored program (the
  batch solves, the quasi-static strokes); :func:`stored_lowering` lowers one for a caller that
  compiles on threads of its own (design's two programs).
- Only a command's own process stores programs (:func:`cardiosoft._cli.prepare_process` calls
  :func:`use_program_store`, beside the compile cache); a library call, or a test calling a
  command's ``main()`` in-process, traces as before. So does a process with several devices
  (a sweep shards its chunks over them): the programs are exported for one.
- The key (:func:`program_key`): the function, the static part of its arguments (the scene's
  or network's structure, the solver preset, the save mode, ...), the tree, shapes and dtypes
  of its array arguments (the batch shape, float64), the device, and the versions of
  cardiosoft (a hash of its sources, so an edited checkout never loads an old program), jax,
  jaxlib, diffrax and equinox. The surrogate's numbers are arguments of the program; its
  structure is in the static part.
- An entry (:data:`FORMAT`) is a header line (JSON: the format, the key, the digest of the
  rest) and then the output's layout and the serialised program. A stale, foreign or corrupt
  entry (another key, a digest that does not match, bytes that do not deserialise) is
  rebuilt, never trusted: the call traces, exports and writes the entry anew.
- What is exported is a function of the arguments' array leaves returning the output's array
  leaves; the output's tree is stored as a layout of plain containers and equinox modules
  whose fields are all arrays (:func:`output_layout`), rebuilt by their constructors. A
  function whose output holds anything else is traced, not stored.
- Gradients: the exported program is whatever the function traces. Design's derivative
  program (one ``jax.jvp`` of the orbits' batch solve, through the orbit's implicit
  derivative) is stored as it is traced: its derivatives are part of the stored StableHLO,
  not taken of it. A call inside another trace (a derivative taken of a solve, design's
  programs calling ``solve_beats``) is part of that trace and never goes to the store.
- :func:`stored_value` keeps a value computed before a solve, the same every run of one input
  (an svZeroDSolver model's solving order: 0.9 s of its 3.3 s warm run; a design search's
  coarse grid, the same for every target on one scene), as a JSON entry of the same format,
  keyed by the input's bytes, and in the process itself.
- Programs shipped with the package (:data:`SHIPPED`, written by ``tools/ship_programs.py``):
  where the store has no entry for a key, a shipped entry of that key is copied into it, so
  that a fresh machine's first run of the main job (or of a shipped scene's design question)
  loads its programs instead of tracing them
  (issue #41, item 2: tracing is 3.7 of the cold main job's 7.6 s). StableHLO is portable
  across CPUs; the executable is compiled on the machine, as before. An entry's header names
  the sources it was traced from (``sources``): an edit of cardiosoft makes every shipped entry
  stale (never found, since the key holds that digest), and ``tests/test_program_store.py``
  says so until they are written again.
- The store keeps at most :data:`STORE_LIMIT_BYTES`: each edit of cardiosoft's sources or
  new version keys new entries (about 0.2 MB each), so writing one deletes the least recently
  used beyond the limit (a read marks an entry used). Deleting the folder is always safe.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import importlib
import json
import os
import sys
import tempfile
from importlib import metadata
from pathlib import Path

__all__ = [
    "FORMAT",
    "SHIPPED",
    "STORE_LIMIT_BYTES",
    "VALUES_KEPT",
    "StoredLowering",
    "output_layout",
    "program_key",
    "prune",
    "read_header",
    "sources_digest",
    "stored_call",
    "stored_lowering",
    "stored_value",
    "use_program_store",
]  # fmt: skip

FORMAT = "cardiosoft-program-1"
"""The entry format: the header's ``format``."""
SUFFIX = ".jaxprogram"
STORE_LIMIT_BYTES = 256 * 2**20
"""The most a store holds: about a thousand programs, every command's for several versions."""

SHIPPED = Path(__file__).resolve().parent / "programs"
"""The programs shipped with the package: the main job's, ``--uncertainty``'s and a design
question's per shipped scene (``tools/ship_programs.py``)."""

# this process's store, the shipped entries it may copy, its programs and values by key
_state = {"folder": None, "shipped": None, "loaded": {}, "values": {}}
VALUES_KEPT = 16
"""The most values :func:`stored_value` keeps in a process (the least recently computed go)."""


def use_program_store(folder: Path | None, shipped: Path | None = None) -> None:
    """Store and load this process's programs in ``folder`` (None: trace every program); an
    entry missing there is copied from ``shipped`` where that folder has it."""
    _state["folder"] = None if folder is None else Path(folder)
    _state["shipped"] = None if shipped is None else Path(shipped)
    _state["loaded"] = {}
    _state["values"] = {}


@functools.cache
def sources_digest() -> str:
    """The SHA-256 of cardiosoft's Python sources (their paths and bytes): part of every key."""
    package = Path(__file__).resolve().parent
    sources = hashlib.sha256()
    for path in sorted(package.rglob("*.py")):
        sources.update(str(path.relative_to(package)).encode() + b"\0" + path.read_bytes())
    return sources.hexdigest()


@functools.cache
def _versions() -> dict:
    return {
        "cardiosoft": sources_digest(),
        **{name: metadata.version(name) for name in ("jax", "jaxlib", "diffrax", "equinox")},
        "python": sys.version.split()[0],
    }


def _is_leaf_value(x) -> bool:
    import equinox as eqx
    import jax

    return eqx.is_array(x) or isinstance(x, jax.ShapeDtypeStruct)


def program_key(name: str, args: tuple, keywords: dict) -> tuple[str, object, object, tuple]:
    """The key of ``name`` called with ``args`` and the static ``keywords`` (module docstring),
    the arguments' static part, their array leaves' tree and the leaves themselves (arrays or
    ``jax.ShapeDtypeStruct``)."""
    import equinox as eqx
    import jax

    dynamic, static = eqx.partition(args, _is_leaf_value)
    leaves, tree = jax.tree.flatten(dynamic)
    described = {
        "name": name,
        "static": repr((static, sorted(keywords.items()))),
        "tree": str(tree),
        "leaves": [f"{leaf.dtype}{list(leaf.shape)}" for leaf in leaves],
        "device": str(jax.devices()[0]),
        "x64": bool(jax.config.jax_enable_x64),
        "versions": _versions(),
    }
    key = hashlib.sha256(json.dumps(described, sort_keys=True).encode()).hexdigest()
    return key, static, tree, tuple(leaves)


def output_layout(tree):
    """The output ``tree`` as a JSON-ready layout, or None where it holds something other than
    plain containers, array leaves, None and equinox modules whose fields are those or (static
    fields) classes."""
    import equinox as eqx

    if tree is None:
        return {"none": True}
    if eqx.is_array(tree):
        return {"leaf": True}
    if type(tree) in (tuple, list):  # not a NamedTuple: its own class rebuilds it
        items = [output_layout(x) for x in tree]
        return None if None in items else {type(tree).__name__: items}
    if isinstance(tree, dict) and all(isinstance(k, str) for k in tree):
        # in the keys' sorted order, as JAX flattens a dict (and a jitted function returns it)
        items = [[k, output_layout(tree[k])] for k in sorted(tree)]
        return None if any(x is None for _, x in items) else {"dict": items}
    if isinstance(tree, type):  # a static field's class (diffrax's RESULTS of a result code)
        return {"type": _path(tree)}
    if isinstance(tree, eqx.Module) and dataclasses.is_dataclass(tree):
        fields = {}
        for field in dataclasses.fields(tree):
            value = getattr(tree, field.name)
            if field.metadata.get("static") and not isinstance(value, type):
                return None
            fields[field.name] = output_layout(value)
        if None in fields.values():
            return None
        return {"module": _path(type(tree)), "fields": fields}
    return None


def _path(cls: type) -> str:
    return f"{cls.__module__}:{cls.__qualname__}"


def _imported(path: str):
    module, qualname = path.split(":")
    value = importlib.import_module(module)
    for part in qualname.split("."):
        value = getattr(value, part)
    return value


def _rebuild(layout, leaves):
    """The output from its ``layout`` and an iterator of its array ``leaves``."""
    if "none" in layout:
        return None
    if "leaf" in layout:
        return next(leaves)
    if "tuple" in layout or "list" in layout:
        kind = tuple if "tuple" in layout else list
        return kind(_rebuild(x, leaves) for x in layout[kind.__name__])
    if "dict" in layout:
        return {k: _rebuild(x, leaves) for k, x in layout["dict"]}
    if "type" in layout:
        return _imported(layout["type"])
    fields = {k: _rebuild(v, leaves) for k, v in layout["fields"].items()}
    return _imported(layout["module"])(**fields)


def read_header(path: Path) -> dict:
    """The header of the entry at ``path``: its ``format``, ``key``, ``kind`` ("program" or
    "value"), the ``sources`` digest it was made from (:func:`sources_digest`), ..."""
    with open(path, "rb") as f:
        return json.loads(f.readline())


def _read(path: Path, key: str, load=None, touch: bool = True):
    """The entry at ``path`` as (layout, program, its bytes), or None when it is missing,
    foreign, stale or corrupt. ``load`` reads the bytes after the layout (default: a
    serialised program); ``touch`` marks the entry used (a store's, not a shipped one)."""
    from jax import export

    load = (lambda raw: export.deserialize(bytearray(raw))) if load is None else load
    try:
        raw = path.read_bytes()
        head, _, body = raw.partition(b"\n")
        header = json.loads(head)
        if header.get("format") != FORMAT or header.get("key") != key:
            return None
        if hashlib.sha256(body).hexdigest() != header.get("digest"):
            return None
        size = header["layout_bytes"]
        layout = json.loads(body[:size])
        program = load(body[size:])
    except Exception:  # any unreadable entry is rebuilt, never trusted
        return None
    if touch:
        try:
            os.utime(path)  # used now: pruned last
        except OSError:
            pass
    return layout, program, raw


def _write(path: Path, key: str, layout, program: bytes, kind: str = "program") -> None:
    text = json.dumps(layout).encode()
    body = text + program
    header = {
        "format": FORMAT, "key": key, "kind": kind, "sources": sources_digest(),
        "digest": hashlib.sha256(body).hexdigest(), "layout_bytes": len(text),
    }  # fmt: skip
    _write_bytes(path, json.dumps(header).encode() + b"\n" + body)


def _write_bytes(path: Path, raw: bytes) -> None:
    """Write an entry atomically (a concurrent reader sees the old entry or the new one), then
    prune the store to its limit."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(raw)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    prune(path.parent, STORE_LIMIT_BYTES)


def _stored_entry(path: Path, key: str, load=None):
    """The store's entry at ``path`` as (layout, program), else the shipped entry of its
    name, copied into the store first; None when neither is there and sound."""
    entry = _read(path, key, load)
    if entry is None and _state["shipped"] is not None:
        entry = _read(_state["shipped"] / path.name, key, load, touch=False)
        if entry is not None:
            try:
                _write_bytes(path, entry[2])  # the next process reads the store only
            except OSError as err:  # a store that cannot be written: this run goes on
                print(f"warning: program store {path.parent}: {err}", file=sys.stderr)
    return None if entry is None else entry[:2]


def prune(folder: Path, limit: int) -> list[Path]:
    """Delete the least recently used entries of ``folder`` (by modification time, which a
    read renews) until the rest hold at most ``limit`` bytes; returns what was deleted."""
    entries = []
    for path in folder.glob(f"*{SUFFIX}"):
        try:
            stat = path.stat()
        except OSError:  # deleted by a concurrent prune
            continue
        entries.append((stat.st_mtime, stat.st_size, path))
    total = sum(size for _, size, _ in entries)
    deleted = []
    for _, size, path in sorted(entries):
        if total <= limit:
            break
        path.unlink(missing_ok=True)
        total -= size
        deleted.append(path)
    return deleted


def _export(fn, keywords, static, tree, leaves):
    """Trace ``fn`` once as a function of the array ``leaves``: (layout, exported program), or
    None when its output cannot be stored. JAX's log names that trace ``<fn>_exported``."""
    import equinox as eqx
    import jax
    from jax import export

    box = {}

    def flat(*leaves):
        out = fn(*eqx.combine(jax.tree.unflatten(tree, leaves), static), **keywords)
        box["layout"] = output_layout(out)
        return jax.tree.leaves(out)

    flat.__name__ = flat.__qualname__ = f"{fn.__name__}_exported"
    shapes = [jax.ShapeDtypeStruct(x.shape, x.dtype) for x in leaves]
    try:
        program = export.export(jax.jit(flat))(*shapes)
    except Exception:  # e.g. host callbacks (a user's EQX_ON_ERROR=raise) do not export: the
        return None  # call is traced as before, and an error of the function's own raised there
    return (box["layout"], program) if box["layout"] is not None else None


@dataclasses.dataclass(frozen=True)
class StoredLowering:
    """A stored program lowered for its arguments' shapes, as ``jax.jit(fn).lower(...)`` is:
    :meth:`compile` (XLA's work, which a thread may do) gives a function of the same
    arguments returning the same tree; :attr:`out_info` is that tree's shapes and dtypes."""

    layout: dict
    lowered: object
    out_info: object

    def compile(self):
        import equinox as eqx
        import jax

        compiled = self.lowered.compile()

        def call(*args):
            leaves = jax.tree.leaves(eqx.filter(args, _is_leaf_value))
            return _rebuild(self.layout, iter(compiled(*leaves)))

        return call


def _stores(args) -> bool:
    """Whether this process stores a program called with ``args``: it keeps a store, has one
    device (a sweep shards a batch over several: its programs are traced, as before), and
    ``args`` are not inside another trace (design's programs call ``solve_beats``)."""
    import jax

    if _state["folder"] is None or jax.device_count() > 1:
        return False
    return not any(isinstance(x, jax.core.Tracer) for x in jax.tree.leaves(args))


def _name(fn) -> str:
    return f"{fn.__module__}.{fn.__qualname__}"


def stored_lowering(fn, *args, **keywords) -> StoredLowering | None:
    """``fn`` lowered for ``args`` (arrays, or ``jax.ShapeDtypeStruct`` leaves, and static
    values) and the static ``keywords``, from its stored program, exported and stored first
    when there is none; None when this process stores no such program (no store, several
    devices) or the program cannot be stored: the caller then traces ``fn`` itself."""
    if not _stores(args):
        return None
    return _lowering(fn, keywords, *program_key(_name(fn), args, keywords))


def _lowering(fn, keywords, key, static, tree, leaves) -> StoredLowering | None:
    import jax

    folder = _state["folder"]
    path = folder / f"{key}{SUFFIX}"
    entry = _stored_entry(path, key)
    if entry is None:
        entry = _export(fn, keywords, static, tree, leaves)
        if entry is None:
            return None
        try:
            _write(path, key, entry[0], entry[1].serialize())
        except OSError as err:  # a store that cannot be written: this run goes on
            print(f"warning: program store {folder}: {err}", file=sys.stderr)
    layout, program = entry

    def call(*leaves):
        return program.call(*leaves)

    call.__name__ = call.__qualname__ = fn.__name__  # JAX's log and compile cache name it
    shapes = [jax.ShapeDtypeStruct(x.shape, x.dtype) for x in leaves]
    out_avals = (jax.ShapeDtypeStruct(a.shape, a.dtype) for a in program.out_avals)
    out_info = _rebuild(layout, out_avals)
    return StoredLowering(layout, jax.jit(call).lower(*shapes), out_info)


def _arrays_to_json(value: dict) -> dict:
    return {k: {"dtype": str(a.dtype), "shape": list(a.shape), "data": a.ravel().tolist()}
            for k, a in value.items()}  # fmt: skip


def _arrays_from_json(value: dict) -> dict:
    import numpy as np

    return {k: np.array(x["data"], dtype=x["dtype"]).reshape(x["shape"]) for k, x in value.items()}


def stored_value(name: str, material, compute, encode=_arrays_to_json, decode=_arrays_from_json):
    """``compute()``, the value of ``material`` (arrays and static values, whose bytes and
    ``repr`` key it), kept in this process (the last :data:`VALUES_KEPT`) and in its store
    beside its programs: what a command computes before it solves, the same every run of one
    input (the solving order of an svZeroDSolver model's nodes, a design search's coarse
    grid). ``encode`` makes the value JSON-ready and ``decode`` takes it back
    (``decode(encode(v))`` must equal ``v``; by default the value is a dict of numpy arrays,
    each kept exactly: float64 through Python's shortest round-trip repr); an entry that is
    missing, stale or corrupt, or does not decode, is computed anew."""
    import equinox as eqx
    import jax
    import numpy as np

    dynamic, static = eqx.partition(material, _is_leaf_value)
    arrays = hashlib.sha256()
    for leaf in jax.tree.leaves(dynamic):
        leaf = np.asarray(leaf)
        arrays.update(f"{leaf.dtype}{list(leaf.shape)}".encode() + leaf.tobytes())
    described = {
        "name": name, "static": repr(static), "arrays": arrays.hexdigest(),
        "x64": bool(jax.config.jax_enable_x64), "versions": _versions(),
    }  # fmt: skip
    key = hashlib.sha256(json.dumps(described, sort_keys=True).encode()).hexdigest()
    values = _state["values"]
    if key not in values:
        values[key] = _value_from_store(key, compute, encode, decode)
        while len(values) > VALUES_KEPT:
            values.pop(next(iter(values)))
    return values[key]


def _value_from_store(key: str, compute, encode, decode):
    if _state["folder"] is None:
        return compute()
    path = _state["folder"] / f"{key}{SUFFIX}"
    entry = _stored_entry(path, key, load=lambda raw: raw)
    if entry is not None:
        try:
            return decode(entry[0])
        except Exception:  # a value this version cannot take back: computed anew
            pass
    value = compute()
    try:
        _write(path, key, encode(value), b"", kind="value")
    except OSError as err:  # a store that cannot be written: this run goes on
        print(f"warning: program store {path.parent}: {err}", file=sys.stderr)
    return value


def stored_call(jitted, *args):
    """``jitted(*args)`` (an ``eqx.filter_jit`` function), through its stored program when
    this process stores it (:func:`stored_lowering`); compiled once a process."""
    if not _stores(args):
        return jitted(*args)
    fn = jitted.__wrapped__
    found = program_key(_name(fn), args, {})
    key = found[0]
    if key not in _state["loaded"]:
        lowering = _lowering(fn, {}, *found)
        _state["loaded"][key] = None if lowering is None else lowering.compile()
    call = _state["loaded"][key]
    return jitted(*args) if call is None else call(*args)
