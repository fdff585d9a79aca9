"""What the command lines share: their parser, options, messages, exit status and process set-up.

Numerics never live here; safe file output is :mod:`cardiosoft.files`. Every command
(``cardiosoft simulate|design|sweep|stress|geometry``, or ``python -m cardiosoft.X``) builds its
parser with :func:`command_parser` and reports through a :class:`Console`:

- **bad input**: one line ``error: <parameter> = <value> <unit> is outside ...`` on stderr,
  exit status 2, nothing written (:func:`fail`; argparse's own errors likewise);
- **progress**: lines and bars on stderr (tqdm; a bar only on a terminal), none with
  ``--quiet``;
- **flags** (a number not to be taken as it is: the surrogate extrapolated, a target that
  cannot be reached, a transient where a fixed number of beats was asked): ``warning: ...`` on
  stderr and ``flags`` in the JSON the command writes; they do not change the exit status
  unless ``--strict``;
- **failures** (a member whose solve failed, or that did not reach the periodic steady state it
  was asked to reach; a hard case that fails): ``failed: ...`` on stderr, exit status 1.

:data:`EXIT_STATUS` says it in the words every ``--help`` ends with.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

from cardiosoft import progress

EXIT_OK, EXIT_FAILED, EXIT_BAD_INPUT = 0, 1, 2
CACHE_VARIABLE = "CARDIOSOFT_COMPILE_CACHE"
"""``0`` switches the compile cache off; a folder puts it there (:func:`use_compile_cache`)."""
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


def add_scene_option(parser, *, static: bool = True) -> None:
    """``--scene``: a shipped scene or a .toml file (``static``: bench-static listed too)."""
    from cardiosoft.scene import SCENE_NAMES

    names = [s for s in SCENE_NAMES if static or s != "bench-static"]
    parser.add_argument(
        "--scene",
        default="bench-dynamic",
        help=f"shipped scene ({', '.join(names)}) or a scene .toml file (default: bench-dynamic)",
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


# ------------------------------------------------------------------------------ what it prints


def fail(err: BaseException) -> int:
    """Print one line for a bad input and return the CLI's bad-input exit code."""
    print(f"error: {err}", file=sys.stderr)
    return EXIT_BAD_INPUT


class Console:
    """A command's messages on stderr, its flags and failures, and its exit status.

    ``quiet``: no progress and no warnings (errors and failures are still printed);
    ``strict``: a flag makes the exit status 1.
    """

    def __init__(self, quiet: bool = False, strict: bool = False):
        self.quiet, self.strict = quiet, strict
        self.flags: list[str] = []
        self.failures: list[str] = []

    def say(self, line: str) -> None:
        """A progress line (written around a progress bar, if one is shown)."""
        if not self.quiet:
            progress.write(line)

    def flag(self, where: str, what: str) -> None:
        """A number not to be taken as it is: a warning line, and the JSON's ``flags``."""
        self.flags.append(f"{where}: {what}" if where else what)
        if not self.quiet:
            print(f"warning: {self.flags[-1]}", file=sys.stderr)

    def fail(self, where: str, what: str) -> None:
        """A member that failed or missed the steady state it was asked for: exit status 1."""
        self.failures.append(f"{where}: {what}" if where else what)
        print(f"failed: {self.failures[-1]}", file=sys.stderr)

    def progress(self, total: int, *, desc: str, unit: str, initial: int = 0):
        """A progress bar (:func:`cardiosoft.progress.bar`): on a terminal, never ``quiet``."""
        return progress.bar(total, desc=desc, unit=unit, enabled=not self.quiet, initial=initial)

    def record(self) -> dict:
        """What the JSON output says of the run's trust: flags, failures, exit status."""
        return {"flags": self.flags, "failures": self.failures, "exit_status": self.status()}

    def status(self) -> int:
        """1 on a failure, or on a flag with ``strict``; else 0."""
        return EXIT_FAILED if self.failures or (self.strict and self.flags) else EXIT_OK


def report_members(console: Console, members, *, steady_asked: bool) -> None:
    """Each member's flags as warnings; a member that is not ok as a failure, unless it only
    stopped short of the steady state where a fixed number of beats was asked (a flag then).

    ``members``: :class:`cardiosoft.results.MemberResult` s (``label``, ``ok``, ``message``,
    ``flags``)."""
    for m in members:
        if not m.ok:
            transient = m.message.startswith("not steady")
            (console.flag if transient and not steady_asked else console.fail)(m.label, m.message)
        for what in m.flags:
            console.flag(m.label, what)


# ------------------------------------------------------------------------------ the process


def prepare_process(tool: str, argv) -> None:
    """Settings of a command's own process, made before JAX starts its backend: never by a
    library import or a ``main()`` that a test calls in-process.

    - simulate, design and ``stress --quick``: XLA's optimisation level 0. Their time is
      compiling: LLVM's optimisation of the generated CPU code is about a third of it and buys
      little for a few solves (simulate's results agree to 1e-13; a design search's calls run
      about 3x slower, ~0.15 s against 0.05 s on the bench, which tens of calls hardly notice).
    - sweep, in this process (not with ``--workers`` / ``--scheduler``, whose workers share the
      cores): as many XLA host devices as cores, so that each chunk is sharded over all of them
      (``benchmarks/sweep_throughput.py``, section 4).
    - simulate, design and sweep: the compile cache (:func:`use_compile_cache`).

    An ``XLA_FLAGS`` of the user's own is left as it is.
    """
    flags = os.environ.get("XLA_FLAGS", "")
    options = {a.split("=")[0] for a in argv}
    if tool in ("simulate", "design") or (tool == "stress" and "--quick" in options):
        os.environ.setdefault("XLA_FLAGS", "--xla_backend_optimization_level=0")
    elif tool == "sweep" and "xla_force_host_platform_device_count" not in flags:
        if not {"--workers", "--scheduler"} & options:
            count = f"--xla_force_host_platform_device_count={os.cpu_count() or 1}"
            os.environ["XLA_FLAGS"] = f"{flags} {count}".strip()
    if tool in ("simulate", "design", "sweep"):
        use_compile_cache()  # the next process loads what this one compiles


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
      (:func:`cardiosoft.solve.orbit_beat`). The whole analysis is in the commit that added
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
    if "EQX_ON_ERROR" not in os.environ:
        import equinox._errors

        # equinox reads EQX_ON_ERROR once, when imported (``import cardiosoft`` did that), and
        # looks this module global up each time it traces a check: set before any tracing.
        if getattr(equinox._errors, "EQX_ON_ERROR", None) == "raise":
            equinox._errors.EQX_ON_ERROR = "nan"
    return folder
