"""What the command lines share: their parser and options, and their process set-up.

Numerics never live here. Every command (``cardiosoft simulate|design|sweep|stress|geometry``,
or ``python -m cardiosoft.X``) builds its parser with :func:`command_parser`: argparse's own
errors are one line and exit status 2, like every other bad input, and ``--help`` ends with the
command's exit status (:data:`EXIT_STATUS`). What a command prints, its flags, failures and exit
status are :mod:`cardiosoft.console`'s; writing outputs whole, :mod:`cardiosoft.files`'s; a
command's own process is set up by :func:`prepare_process` (XLA flags, the compile cache).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

from cardiosoft.console import EXIT_BAD_INPUT

CACHE_VARIABLE = "CARDIOSOFT_COMPILE_CACHE"
"""``0`` switches the compile cache off; a folder puts it there (:func:`use_compile_cache`)."""
STORE_VARIABLE = "CARDIOSOFT_PROGRAM_STORE"
"""``0`` switches the store of exported programs off (:mod:`cardiosoft.program_store`); it
lives in the compile cache's folder and is off with it."""
SHIPPED_VARIABLE = "CARDIOSOFT_SHIPPED_PROGRAMS"
"""``0``: a program missing from the store is traced, never copied from the programs shipped
with the package (:data:`cardiosoft.program_store.SHIPPED`; the benchmarks' cold runs)."""
EXIT_STATUS = (
    "exit status: 0 when it did what was asked (flags: {flags}; they are printed as warnings "
    "and listed under 'flags' in {output}); 1 when {failure}; 2 for bad input (one line, "
    "nothing written). --strict turns a flag into exit status 1."
)
"""The exit-status paragraph of every command's ``--help`` (DESIGN.md section 4)."""


# ------------------------------------------------------------------------------ the parser


class Parser(argparse.ArgumentParser):
    """argparse whose errors are one line and exit status 2, like every other bad input."""

    def error(self, message):
        print(f"error: {message} (see {self.prog} --help)", file=sys.stderr)
        raise SystemExit(EXIT_BAD_INPUT)


def command_parser(
    name: str, description: str, *, prog: str | None = None, flags=None, failure=None, output=""
) -> Parser:
    """The parser of ``cardiosoft <name>`` (``prog``; default ``python -m cardiosoft.<name>``),
    its help ending with the exit status: what a flag and a failure are for this command
    (``flags``, ``failure``: phrases; None for a command that has neither)."""
    if flags is None:
        epilog = "exit status: 0 when it did what was asked; 2 for bad input (one line)."
    else:
        epilog = EXIT_STATUS.format(flags=flags, failure=failure, output=output or "the output")
    return Parser(
        prog=prog or f"python -m cardiosoft.{name}", description=description, epilog=epilog
    )


def allowed(field: str, left: str = "[") -> str:
    """The allowed range of a scene number (:data:`cardiosoft.scene.RANGES`), as help text."""
    from cardiosoft.scene import RANGES

    lo, hi = RANGES[field]
    return f"{left}{lo:g}, {hi:g}]"


def add_scene_option(
    parser, *, static: bool = True, loops: bool = False, models: str | None = None
) -> None:
    """``--scene``: a shipped scene or a .toml file (``static``: bench-static listed too;
    ``loops``: the closed-loop scenes too; ``models``: an svZeroDSolver model too, and what the
    command does with it)."""
    from cardiosoft.scene import LOOP_SCENE_NAMES, SCENE_NAMES

    names = [s for s in SCENE_NAMES if static or s != "bench-static"]
    closed = f"; closed loops: {', '.join(LOOP_SCENE_NAMES)}" if loops else ""
    model = f", or an svZeroDSolver model .json ({models})" if models else ""
    parser.add_argument(
        "--scene",
        default="bench-dynamic",
        help=f"shipped scene ({', '.join(names)}{closed}), a scene .toml file{model} "
        "(default: bench-dynamic)",
    )
    add_pump_option(parser)


MODEL_OPTIONS = ("pump_chamber", "units")
"""The options that only an svZeroDSolver model takes (:func:`add_model_options`)."""


def add_model_options(parser, pump_chamber: str):
    """The group of options for an svZeroDSolver model (``--scene model.json``):
    ``--pump-chamber NAME`` (``pump_chamber``: what the command does with the pump there) and
    ``--units``. Returns the group, for a command's own model options."""
    from cardiosoft.network.pump_in_model import DEFAULT_UNITS, UNIT_SYSTEMS

    group = parser.add_argument_group("svZeroDSolver models (--scene model.json)")
    group.add_argument("--pump-chamber", metavar="NAME", help=pump_chamber)
    group.add_argument(
        "--units",
        choices=tuple(UNIT_SYSTEMS),
        help=f"the model's units, where the pump (SI inside) meets it (default {DEFAULT_UNITS}; "
        "mmHg: mmHg, ml, s; si: Pa, m^3, s)",
    )
    return group


def refuse_model_options(args, own: tuple[str, ...] = ()) -> None:
    """``ValueError`` naming the first of :data:`MODEL_OPTIONS` and the command's ``own`` model
    options given with a scene that is not an svZeroDSolver model."""
    for option in (*MODEL_OPTIONS, *own):
        if getattr(args, option, None) is not None:
            flag = "--" + option.replace("_", "-")
            raise ValueError(f"{flag}: only with an svZeroDSolver model (--scene *.json)")


def add_pump_option(parser) -> None:
    """``--pump``: the surrogate a scene runs, in place of the scene's own (its key 'pump')."""
    from cardiosoft.pump import DEFAULT_ARTIFACT, SHIPPED_ARTIFACTS

    parser.add_argument(
        "--pump",
        metavar="NAME",
        help=f"pump surrogate: {', '.join(SHIPPED_ARTIFACTS)} or a surrogate's .eqx file "
        f"(default: the scene's key 'pump', else {DEFAULT_ARTIFACT}); the bench scenes carry "
        "their rig's calibration for each shipped pump",
    )


def add_output_options(parser, files: str, *, plot: str | None = None) -> None:
    """``--out DIR`` (``files`` written there), ``--no-plot`` (when a ``plot`` is among them:
    its name), ``--force``."""
    parser.add_argument("--out", metavar="DIR", help=f"write {files} there")
    if plot is not None:
        parser.add_argument("--no-plot", action="store_true", help=f"with --out: skip {plot}")
    parser.add_argument("--force", action="store_true", help="overwrite existing files in --out")


def add_report_options(parser) -> None:
    """``--strict`` and ``--quiet``."""
    parser.add_argument(
        "--strict", action="store_true", help="exit with status 1 when anything is flagged"
    )
    parser.add_argument("--quiet", action="store_true", help="print nothing but errors")


def values_argument(items):
    """argparse's list of ``nargs="+"`` strings as :func:`cardiosoft._validate.parse_values`
    takes it: one item as it is (it may be START:STOP:N), several as numbers."""
    if items is None:
        return None
    from cardiosoft._validate import parse_values

    if len(items) == 1:
        return items[0]
    out = []
    for item in items:
        out += parse_values(item, "value")
    return out


# ------------------------------------------------------------------------------ the process


FAST_COMPILE_FLAGS = ("--xla_backend_optimization_level=0", "--xla_cpu_use_fusion_emitters=false")
"""XLA flags for a process whose time is compiling. Measured on the design search's programs
(CPU seconds of XLA's compile, one thread, jaxlib 0.10.2, 2 loaded cores): the classic emitters
compile the bench's orbits in 5.2-5.8 s against 6.9-7.8 s and their derivatives in 2.5-3.2 s
against 5.9-6.8 s, lv-systemic's in 8.7 and 3.6 s against 10.0 and 8.5 s; the compiled calls
are no slower (lv-systemic's orbits 1.0 s against 1.3 s)."""


SOLVES_MORE_THAN_COMPILES = frozenset({"--uncertainty"})
"""Options whose command spends more time solving than compiling: XLA keeps its own settings.
``simulate --bpm 60 --uncertainty`` (48 draws x 3 heads, the batch running until its slowest
draw settles, up to 300 beats) from fresh processes on 2 cores, 2026-12-06: with
:data:`FAST_COMPILE_FLAGS` 33.7 s cold and 18.0 s warm; with XLA's defaults 33.1 s and 6.7 s;
with the classic emitters alone 34.0 s and 8.3 s. (The design searches of the pump scenes were
measured too and keep the flags: the bench's 23.1 s cold against 32.4 s at XLA's defaults, warm
3.8 s against 3.5 s; the closed loops' do not, :func:`solves_more_than_compiles`.)"""


def solves_more_than_compiles(tool: str, argv) -> bool:
    """Whether ``tool`` run with ``argv`` spends more time solving than compiling: an option of
    :data:`SOLVES_MORE_THAN_COMPILES`, or ``design`` on a closed loop
    (:func:`cardiosoft.scene.is_closed_loop`). A closed loop's design shoots to the periodic
    orbit some 50 times (Newton on an 11-state map, each iteration a beat with its
    derivatives); at XLA's defaults, against level 0, from fresh processes on 2 cores
    (2026-12-07, a cold and two warm runs each): ``tah`` (``--target-co 5 --lap 8 --rap 5``)
    57.4 -> 41.3 s cold and 34.6 -> 14.8 s warm, ``soft-lv`` (``--target-co 4.5``) 33.1 ->
    30.7 s and 16.4 -> 9.4 s, ``soft-rv`` 27.6 -> 28.0 s and 8.7 -> 7.1 s. Tests and
    notebooks, run in-process, run at XLA's defaults too."""
    options = {a.split("=")[0] for a in argv}
    if SOLVES_MORE_THAN_COMPILES & options:
        return True
    if tool != "design":
        return False
    from cardiosoft.scene import is_closed_loop

    scene = _option_value(argv, "--scene")
    return scene is not None and is_closed_loop(scene)


def _option_value(argv, option: str) -> str | None:
    """The value of ``option`` in ``argv`` (``--scene X`` or ``--scene=X``; the last one)."""
    value = None
    for i, arg in enumerate(argv):
        if arg == option and i + 1 < len(argv):
            value = argv[i + 1]
        elif arg.startswith(option + "="):
            value = arg.partition("=")[2]
    return value


def fast_compile_flags() -> tuple[str, ...]:
    """:data:`FAST_COMPILE_FLAGS` that the installed XLA takes: XLA aborts the process on a flag
    it does not know, so the emitters' flag is given only to the jaxlib it was measured with
    (the 0.10 series; pyproject.toml allows < 0.11)."""
    from importlib import metadata

    try:
        major_minor = tuple(int(p) for p in metadata.version("jaxlib").split(".")[:2])
    except (metadata.PackageNotFoundError, ValueError):
        major_minor = (0, 0)
    return FAST_COMPILE_FLAGS if major_minor >= (0, 10) else FAST_COMPILE_FLAGS[:1]


def xla_flags(tool: str, argv, current: str | None) -> str | None:
    """The ``XLA_FLAGS`` that ``tool`` run with ``argv`` sets (:func:`prepare_process`), given
    the ``current`` one (None: unset); None leaves it as it is."""
    options = {a.split("=")[0] for a in argv}
    compiling = tool in ("simulate", "design") or (tool == "stress" and "--quick" in options)
    if compiling and not solves_more_than_compiles(tool, argv):
        return " ".join(fast_compile_flags()) if current is None else None
    flags = current or ""
    if tool == "sweep" and "xla_force_host_platform_device_count" not in flags:
        if not {"--workers", "--scheduler"} & options:
            count = f"--xla_force_host_platform_device_count={os.cpu_count() or 1}"
            return f"{flags} {count}".strip()
    return None


def prepare_process(tool: str, argv) -> None:
    """Settings of a command's own process, made before JAX starts its backend: never by a
    library import or a ``main()`` that a test calls in-process.

    - simulate, design and ``stress --quick``: XLA's optimisation level 0. Their time is
      compiling: LLVM's optimisation of the generated CPU code is about a third of it and buys
      little for a few solves (simulate's results agree to 1e-13; a design search's calls run
      about 3x slower, ~0.15 s against 0.05 s on the bench, which tens of calls hardly notice).
      With jaxlib 0.10 (where it was measured) also XLA's classic CPU emitters instead of its
      fusion emitters (:data:`FAST_COMPILE_FLAGS`). Not where solving dominates
      (:func:`solves_more_than_compiles`): ``--uncertainty``, whose posterior's draws are
      solved 3.5x slower at level 0 and compiled no faster, and a closed loop's design.
    - sweep, in this process (not with ``--workers`` / ``--scheduler``, whose workers share the
      cores): as many XLA host devices as cores, so that each chunk is sharded over all of them
      (``benchmarks/sweep_throughput.py``, section 4).
    - simulate, design, sweep and credibility: the compile cache (:func:`use_compile_cache`),
      and in its folder ``programs/`` the exported programs that spare a process the tracing
      (:mod:`cardiosoft.program_store`; :data:`STORE_VARIABLE` switches them off), filled
      first from the programs shipped with the package (:data:`SHIPPED_VARIABLE`).

    An ``XLA_FLAGS`` of the user's own is left as it is.
    """
    flags = xla_flags(tool, argv, os.environ.get("XLA_FLAGS"))
    if flags is not None:
        os.environ["XLA_FLAGS"] = flags
    if tool in ("simulate", "design", "sweep", "credibility"):
        from cardiosoft.program_store import SHIPPED, use_program_store

        folder = use_compile_cache()  # the next process loads what this one compiles
        if folder is not None and os.environ.get(STORE_VARIABLE, "").strip() != "0":
            shipped = os.environ.get(SHIPPED_VARIABLE, "").strip() != "0"
            use_program_store(folder / "programs", SHIPPED if shipped else None)  # and traced


def compile_cache_folder() -> Path | None:
    """Where the compile cache lives: ``$CARDIOSOFT_COMPILE_CACHE`` if it names a folder, None
    if it is ``0``, else ``$XDG_CACHE_HOME/cardiosoft/jax`` (``~/.cache/cardiosoft/jax``)."""
    setting = os.environ.get(CACHE_VARIABLE, "").strip()
    if setting == "0":
        return None
    if setting and setting != "1":
        return Path(setting).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "cardiosoft" / "jax"


def use_compile_cache() -> Path | None:
    """Keep the CLI's compiled programs on disk, so that the next process loads them instead of
    compiling them again (JAX's persistent compilation cache). Returns the folder, or None.

    Nearly all of a fresh CLI process's time is tracing and compiling the same few programs
    (benchmarks/startup.py, benchmarks/design.py); tracing is redone, XLA compilation is not.
    Call it in a command's own process only (:func:`prepare_process`), before anything is
    compiled: library imports and the ``main()`` functions (which tests call in-process) leave
    JAX's global settings alone.

    - On by default; ``CARDIOSOFT_COMPILE_CACHE=0`` switches it off, ``=/some/folder`` moves it.
      A cache folder of the user's own (``JAX_COMPILATION_CACHE_DIR``) is kept as it is.
    - A folder that cannot be created or written: one warning line, and the run goes on
      without a cache.
    - JAX refuses to store a program with host callbacks, and equinox's runtime checks
      (``eqx.error_if``, inside diffrax) are host callbacks that raise: the batch solve would
      never be stored. The process therefore resolves those checks to NaN instead
      (``EQX_ON_ERROR=nan``), unless the user chose a mode. cardiosoft never relies on them
      being raised: its solves run with ``throw=False`` and report diffrax's result codes; the
      checks left are diffrax's on the save times (which cardiosoft builds increasing, clipped
      to the beat: a violation would give non-finite samples, which ``periodic_beats`` reports
      as a failed solve) and lineax's on the derivatives of a stiff solver's linear solves,
      which the implicit derivative of an orbit never feeds a NaN
      (:func:`cardiosoft.shooting.orbit_beat`). The whole analysis is in the commit that added
      this function.
    """
    import jax

    if os.environ.get("JAX_COMPILATION_CACHE_DIR"):  # JAX itself reads it: the user's own
        folder = Path(os.environ["JAX_COMPILATION_CACHE_DIR"])
    else:
        folder = compile_cache_folder()
        if folder is None:
            return None
        try:
            folder.mkdir(parents=True, exist_ok=True)
            with tempfile.TemporaryFile(dir=folder):  # writable? (os.access ignores root, ACLs)
                pass
        except OSError as err:
            print(
                f"warning: compile cache {folder}: {err.strerror or err}; running without it "
                f"(set {CACHE_VARIABLE}=0 to silence this)",
                file=sys.stderr,
            )
            return None
        jax.config.update("jax_compilation_cache_dir", str(folder))
    # JAX stores only programs that took over 1 s to compile; whether the static strokes do
    # depends on the machine and its load (CI once compiled them faster and never stored
    # them). The CLI's programs are few and small on disk: store them all.
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    if "EQX_ON_ERROR" not in os.environ:
        import equinox._errors

        # equinox reads EQX_ON_ERROR once, when imported (``import cardiosoft`` did that), and
        # looks this module global up each time it traces a check: set before any tracing.
        if getattr(equinox._errors, "EQX_ON_ERROR", None) == "raise":
            equinox._errors.EQX_ON_ERROR = "nan"
    return folder
