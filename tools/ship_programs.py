"""Write the programs shipped with the package (``cardiosoft/programs/``, issue #41, item 2).

    python tools/ship_programs.py        # about 2.5 minutes on 2 cores

A fresh machine's first run of a command traces its programs: of the main job's cold 7.6 s,
3.7 s. A program exported with ``jax.export`` is StableHLO, portable across CPUs, so the
package carries those of :data:`SHIPPED_COMMANDS` (the main job, ``--uncertainty``, a design
question per shipped scene): a first run copies them into its store
(:mod:`cardiosoft.program_store`) and only compiles them.

Each command of :data:`COMMANDS` runs here in a fresh process with an empty cache folder and
nothing shipped (``CARDIOSOFT_SHIPPED_PROGRAMS=0``), so every program is traced from the
current sources; the programs it exported replace the folder's. Run it after any change to
cardiosoft's sources: every entry's key holds the sources' digest, so an edit leaves the
shipped programs unused (never wrong), and ``tests/test_program_store.py`` fails until they
are written again.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path[:0] = [str(REPO), str(REPO / "benchmarks")]  # cardiosoft, and what startup.py times

from startup import COMMANDS as TIMED  # noqa: E402

from cardiosoft.program_store import SHIPPED, SUFFIX, read_header  # noqa: E402

SHIPPED_COMMANDS = (
    "main", "uncertainty", "design-bench", "design-lv", "design-rv", "design-soft-lv",
    "design-soft-rv", "design-tah",
)  # fmt: skip
"""What is shipped: the programs of these commands of ``benchmarks/startup.py``."""
COMMANDS = tuple(tuple(TIMED[name][0]) for name in SHIPPED_COMMANDS)


def traced_programs(command, cache: Path) -> list[Path]:
    """Run ``python -m command`` with its cache in ``cache`` and nothing shipped; the program
    entries it stored."""
    env = {
        **os.environ, "CARDIOSOFT_COMPILE_CACHE": str(cache), "CARDIOSOFT_SHIPPED_PROGRAMS": "0",
        "CARDIOSOFT_PROGRAM_STORE": "1",
    }  # fmt: skip
    subprocess.run(
        [sys.executable, "-m", *command, "--quiet"], cwd=REPO, env=env, check=True, timeout=1200
    )
    entries = (cache / "programs").glob(f"*{SUFFIX}")
    return [path for path in entries if read_header(path).get("kind") == "program"]


def main() -> int:
    with tempfile.TemporaryDirectory() as folder:
        entries = set()  # the commands share one folder: a program two of them run is
        for command in COMMANDS:  # traced once
            start = time.perf_counter()
            found = set(traced_programs(command, Path(folder)))
            print(f"{' '.join(command)}: {len(found - entries)} new programs in "
                  f"{time.perf_counter() - start:.1f} s")  # fmt: skip
            entries |= found
        SHIPPED.mkdir(exist_ok=True)
        for old in SHIPPED.glob(f"*{SUFFIX}"):
            old.unlink()
        for path in sorted(entries):
            (SHIPPED / path.name).write_bytes(path.read_bytes())
    total = sum(p.stat().st_size for p in SHIPPED.glob(f"*{SUFFIX}"))
    print(f"wrote {len(entries)} programs to {SHIPPED.relative_to(REPO)}, "
          f"{total / 2**20:.2f} MiB")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
