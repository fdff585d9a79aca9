"""Progress output of long runs, on stderr: one tqdm bar and one line writer for every tool.

A bar is drawn only on a terminal (tqdm's ``disable=None``), so that logs, pipes and tests get
no bar; lines are written through tqdm, so that they never break a bar that is shown.
"""

from __future__ import annotations

import sys

__all__ = ["bar", "write"]


def bar(total: int, *, desc: str, unit: str, enabled: bool = True, initial: int = 0):
    """A progress bar of ``total`` ``unit`` s (a context manager; ``update(n)``), shown on a
    terminal only and never when not ``enabled``."""
    from tqdm.auto import tqdm

    return tqdm(
        total=total,
        initial=initial,
        desc=desc,
        unit=unit,
        disable=None if enabled else True,  # None: off unless stderr is a terminal
        file=sys.stderr,
        mininterval=1.0,
        smoothing=0.1,
        dynamic_ncols=True,
    )


def write(line: str, file=None) -> None:
    """One line of progress (stderr by default), written around a bar that is shown."""
    from tqdm import tqdm

    tqdm.write(line, file=sys.stderr if file is None else file)
