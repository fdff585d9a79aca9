"""What a command says besides its results, and its exit status (DESIGN.md section 4).

- **bad input**: one line ``error: ...`` on stderr, exit status 2, nothing written (:func:`fail`);
- **progress**: lines (and a bar on a terminal) on stderr, none with ``--quiet``
  (:mod:`cardiosoft.progress`);
- **flags** (a number not to be taken as it is: the surrogate extrapolated, a target that
  cannot be reached, a transient where a fixed number of beats was asked): ``warning: ...`` on
  stderr and ``flags`` in the JSON the command writes; exit status 0 unless ``--strict``;
- **failures** (a member whose solve failed, or that did not reach the periodic steady state it
  was asked to reach; a hard case that fails): ``failed: ...`` on stderr, exit status 1.

Its printed tables (:func:`table`, :func:`fmt`) are the commands' and the studies' in ``fit/``.
"""

from __future__ import annotations

import math
import sys

from cardiosoft import progress

__all__ = [
    "EXIT_BAD_INPUT",
    "EXIT_FAILED",
    "EXIT_OK",
    "Console",
    "fail",
    "fmt",
    "report_members",
    "table",
]

EXIT_OK, EXIT_FAILED, EXIT_BAD_INPUT = 0, 1, 2


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

    def conclude(self, result, text: str | None, write=None) -> int:
        """Print ``text`` (an answer's report), fail ``result.failures``, flag
        ``result.flags``, ``write()`` the files, and return the exit status: the end of the
        design commands, open and closed-loop."""
        if text is not None:
            print(text)
        for what in result.failures:
            self.fail("", what)
        for what in result.flags:
            self.flag("", what)
        if write is not None:
            write()
        return self.status()


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


def fmt(value, spec: str) -> str:
    """A number of a printed table: ``-`` for none or a non-finite one."""
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "-"
    return format(value, spec)


def table(header, units, rows) -> str:
    """A printed table: a header line, a units line, then the rows, each column right-aligned."""
    widths = [max(len(x) for x in col) for col in zip(header, units, *rows, strict=True)]
    line = "  ".join
    out = [
        line(h.rjust(w) for h, w in zip(header, widths, strict=True)),
        line(u.rjust(w) for u, w in zip(units, widths, strict=True)),
    ]
    out += [line(c.rjust(w) for c, w in zip(row, widths, strict=True)) for row in rows]
    return "\n".join(out)
