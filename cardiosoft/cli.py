"""The ``cardiosoft`` command: one entry point whose subcommands are the tools' command lines.

    cardiosoft simulate --bpm 60
    cardiosoft design --target-sv 70 --afterload 90 --bpm 60
    cardiosoft sweep --omega 1:5:64 --shortening 0.2:0.6:64 --afterload 60 --out maps/
    cardiosoft stress --quick
    cardiosoft geometry
    cardiosoft --version

``cardiosoft X ...`` and ``python -m cardiosoft.X ...`` run the same ``main()`` of the tool
(:data:`COMMANDS`) with the same process set-up (:func:`cardiosoft._cli.prepare_process`);
``python -m cardiosoft`` is this command. Every subcommand takes ``--help``, whose last paragraph
says its exit status: 0 when it did what was asked (flags are warnings), 1 when a member failed
or missed the steady state it was asked to reach (``--strict``: also when anything is flagged),
2 for bad input.

Shell completion is not offered: argcomplete, the library that would give it, runs the
command's parser on every key press, and building these parsers imports JAX and the scenes
(about 2 s); it would also need a registration step in the user's shell.
"""

from __future__ import annotations

import argparse
import importlib
import sys

__all__ = ["COMMANDS", "main", "run", "version"]

COMMANDS = {
    "simulate": (
        "cardiosoft.simulate",
        "simulate the pump in a scene: stroke volumes, force, work, efficiency",
    ),
    "design": (
        "cardiosoft.design.cli",
        "find the design (Omega, C) that hits target stroke volumes",
    ),
    "sweep": ("cardiosoft.sweep.cli", "design-space maps over Omega x C x afterload x bpm"),
    "stress": ("cardiosoft.stress.cli", "the hard-case suite"),
    "geometry": ("cardiosoft.geometry.cli", "the geometrical model's Fig. 7(a) table"),
    "export": ("cardiosoft.network.export_cli", "write a scene as an svZeroDSolver model"),
    "credibility": (
        "cardiosoft.credibility.cli",
        "the credibility report (ASME V&V 40): the evidence recomputed, a verdict per check",
    ),
}
"""Subcommand: (the module whose ``main(argv, prog)`` it runs, one line of help)."""


def version() -> str:
    """The installed distribution's version (its metadata); the package's own without one."""
    from importlib import metadata

    try:
        return metadata.version("cardiosoft")
    except metadata.PackageNotFoundError:  # run from a source tree that is not installed
        import cardiosoft

        return cardiosoft.__version__


def _parser() -> argparse.ArgumentParser:
    from cardiosoft._cli import Parser

    listed = "\n".join(f"  {name:<10} {text}" for name, (_, text) in COMMANDS.items())
    p = Parser(
        prog="cardiosoft",
        description="A differentiable model of a cable-driven soft pump used as an artificial "
        "heart ventricle.",
        epilog=f"commands:\n{listed}\n\n'cardiosoft COMMAND --help' describes each, its exit "
        "status included:\n0 done (flags are warnings), 1 a member failed or missed the steady "
        "state asked for\n(--strict: or anything was flagged), 2 bad input.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--version", action="version", version=f"cardiosoft {version()}")
    p.add_argument("command", choices=COMMANDS, metavar="COMMAND", help="one of the commands below")
    p.add_argument("arguments", nargs=argparse.REMAINDER, help="the command's own arguments")
    return p


def main(argv=None) -> int:
    """Run ``cardiosoft COMMAND ...`` in this process, as it is (tests call it); returns the
    exit status. :func:`run` is the installed command, which also sets up the process."""
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = _parser()
    if not argv:
        parser.error(f"a COMMAND is needed: {', '.join(COMMANDS)}")
    args = parser.parse_args(argv)
    module = importlib.import_module(COMMANDS[args.command][0])
    return module.main(args.arguments, prog=f"cardiosoft {args.command}")


def run() -> int:
    """The ``cardiosoft`` console script and ``python -m cardiosoft``: the process set-up of the
    command (before JAX starts), then :func:`main`."""
    from cardiosoft._cli import prepare_process

    argv = sys.argv[1:]
    if argv and argv[0] in COMMANDS:
        prepare_process(argv[0], argv[1:])
    return main(argv)
