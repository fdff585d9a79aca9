"""Execute the notebooks in place, outputs and figures included; regenerate the README's figure.

    python notebooks/execute.py                   # every notebook, about 11 min on 2 CPU cores
    python notebooks/execute.py fig10_bench       # some of them (names without .ipynb)
    python notebooks/execute.py --check           # execute, compare with what is stored, write
                                                  # nothing; exit status 1 on a difference

Each notebook runs top to bottom in a fresh Jupyter kernel of this Python (``sys.executable``,
so the project's virtual environment), with ``notebooks/`` as the working directory, as Jupyter
runs it; ``JAX_ENABLE_X64`` is removed from the kernel's environment, so a notebook has float64
only if it switches it on itself. The executed notebook is written back with its outputs, so it
reads on any repository viewer. The figure of the cell tagged ``readme-figure`` is also written
to ``notebooks/figures/<notebook>.png``, which the top-level README shows.

**What is compared** (here with ``--check``, and by ``tests/test_notebooks.py``): the text
outputs of every code cell (printed text, and the ``text/plain`` and ``text/markdown`` of
displays; not images, not stderr), line by line (:func:`compare`). The words must be the same;
the numbers in them are compared with a tolerance (:func:`same_number`), so that another CPU's
round-off does not fail the comparison:

- a whole number (``17 beats``, ``34 right``) must be the same;
- a decimal within :data:`RTOL` (1e-4) of the stored one, plus one unit of its last printed
  digit (1.00 and 1.01 may be the same value, 1.004996 and 1.005003, rounded apart). Why 1e-4:
  the printed numbers come from adaptive solves at the 'default' preset (rtol 1e-6, atol 1e-9
  m^3) or tighter; another machine's rounding may change an adaptive step, which moves a result
  by up to the preset's error: measured 4e-5 relative on the SV of lv-systemic between the
  command line (XLA at -O0) and the API (``tests/test_trust.py``), 1e-5 on the bench
  (``notebooks/accuracy.ipynb``). A model change moves them by far more.

Cell tags (``metadata.tags``) set exceptions:

- ``timing``: wall-clock times, different on every run; never compared;
- ``roundoff``: errors, differences of two solves, cycle changes, ratios of such: numbers at
  the level of the solver's tolerance or of round-off, which another machine changes by more
  than 1e-4 relative. Their numbers must agree within a factor :data:`ROUNDOFF_FACTOR` (10),
  or both be below :data:`ROUNDOFF_FLOOR`; their words exactly;
- ``subset``: under :data:`SMOKE` (a smaller computation, for the tests) every line the smoke
  run prints must be one of the stored lines (numbers as above); without it, compared whole;
- ``full-only``: not compared under :data:`SMOKE`.

Needs ``nbclient``, ``nbformat`` and ``ipykernel`` (the ``test`` extra: ``pip install -e
".[test]"``).
"""

from __future__ import annotations

import argparse
import base64
import contextlib
import json
import os
import re
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
FIGURES = HERE / "figures"
SMOKE = "CARDIOSOFT_NOTEBOOK_SMOKE"
"""Environment variable: set to 1, ``notebooks/accuracy.ipynb`` computes a subset (the tests)."""
TIMEOUT = 3600  # s, per cell
TEXT_TYPES = ("text/plain", "text/markdown")
RTOL = 1e-4
"""Relative tolerance of a printed decimal (module docstring: the 'default' preset's error)."""
ROUNDOFF_FACTOR = 10.0
"""How far apart two numbers of a ``roundoff`` cell may be: within this factor of each other."""
ROUNDOFF_FLOOR = 1e-12
"""Numbers of a ``roundoff`` cell both below this (in their printed unit) are the same: 0 and
3e-16 are both round-off."""
NUMBER = re.compile(r"(?<![\d.])[-+]?(?:\d+\.\d*|\.\d+|\d+)(?:[eE][-+]?\d+)?")
"""A printed number: digits with an optional sign, decimals and exponent (not a digit that
continues another number)."""


def notebooks(names=()) -> list[Path]:
    """The notebooks of ``notebooks/`` (all of them, or those named, without ``.ipynb``)."""
    every = sorted(HERE.glob("*.ipynb"))
    if not names:
        return every
    found = {p.stem: p for p in every}
    missing = [n for n in names if n.removesuffix(".ipynb") not in found]
    if missing:
        raise SystemExit(f"no notebook {', '.join(missing)} in {HERE} (have {', '.join(found)})")
    return [found[n.removesuffix(".ipynb")] for n in names]


@contextlib.contextmanager
def kernel_manager():
    """A kernel manager whose ``python3`` kernel is this interpreter, whatever else is installed.

    The kernel spec lives in a temporary folder that is the only one searched, so a ``python3``
    kernel of another environment (in ``~/.local/share/jupyter``, say) cannot be picked up.
    """
    from jupyter_client.kernelspec import KernelSpecManager
    from jupyter_client.manager import KernelManager

    with tempfile.TemporaryDirectory(prefix="cardiosoft-kernel-") as tmp:
        spec = Path(tmp) / "kernels" / "python3"
        spec.mkdir(parents=True)
        argv = [sys.executable, "-m", "ipykernel_launcher", "-f", "{connection_file}"]
        (spec / "kernel.json").write_text(
            json.dumps({"argv": argv, "display_name": "Python 3 (ipykernel)", "language": "python"})
        )
        ksm = KernelSpecManager(kernel_dirs=[str(spec.parent)], ensure_native_kernel=False)
        yield KernelManager(kernel_name="python3", kernel_spec_manager=ksm)


def kernel_env(smoke: bool) -> dict[str, str]:
    """The kernel's environment: this one without JAX_ENABLE_X64 and a matplotlib backend."""
    env = {k: v for k, v in os.environ.items() if k not in ("JAX_ENABLE_X64", "MPLBACKEND")}
    env.pop(SMOKE, None)
    if smoke:
        env[SMOKE] = "1"
    return env


def execute(path: Path, *, smoke: bool = False, probe: str | None = None):
    """Execute a copy of the notebook at ``path``; return ``(notebook, probe output)``.

    ``probe``: code run in a cell appended at the end (and removed again before returning), to
    ask the kernel what the notebook left (e.g. whether float64 is on); its printed text is
    returned. Raises ``nbclient.exceptions.CellExecutionError`` when a cell fails.
    """
    import nbformat
    from nbclient import NotebookClient

    nb = nbformat.read(path, as_version=4)
    if probe is not None:
        nb.cells.append(nbformat.v4.new_code_cell(probe))
    with kernel_manager() as km:
        client = NotebookClient(
            nb,
            km=km,
            timeout=TIMEOUT,
            record_timing=False,  # no timestamps in the stored notebook
            resources={"metadata": {"path": str(HERE)}},  # the working directory
        )
        client.execute(env=kernel_env(smoke))
    probed = None
    if probe is not None:
        cell = nb.cells.pop()
        probed = "".join(o.get("text", "") for o in cell.outputs if o.output_type == "stream")
    return nb, probed


def tags(cell) -> set[str]:
    return set(cell.get("metadata", {}).get("tags", []))


def texts(cell) -> str:
    """A code cell's compared text: stdout, and the text of displays and results, in order."""
    parts = []
    for out in cell.get("outputs", []):
        if out["output_type"] == "stream" and out.get("name") == "stdout":
            parts.append(_join(out["text"]))
        elif out["output_type"] in ("display_data", "execute_result"):
            for mime in TEXT_TYPES:
                if mime in out.get("data", {}):
                    parts.append(f"[{mime}]\n" + _join(out["data"][mime]) + "\n")
    return "".join(parts)


def _join(text) -> str:
    return "".join(text) if isinstance(text, list) else text


def stored_problems(nb) -> list[str]:
    """What makes a stored notebook not read as executed: cells not run, errors, no figure."""
    problems, images = [], 0
    for i, cell in enumerate(nb.cells):
        if cell.cell_type != "code":
            continue
        if cell.get("execution_count") is None:
            problems.append(f"cell {i} has not been executed")
        for out in cell.get("outputs", []):
            if out["output_type"] == "error":
                problems.append(f"cell {i} stores an error: {out.get('ename')}")
            if "image/png" in out.get("data", {}):
                images += 1
    if images == 0:
        problems.append("no figure is stored")
    return problems


def _unit(token: str) -> float:
    """One unit of the last printed digit of ``token`` (0.01 for ``1.25``, 1e-5 for ``1.0e-04``)."""
    mantissa, _, exponent = token.lower().partition("e")
    decimals = len(mantissa.partition(".")[2])
    return 10.0 ** (int(exponent or 0) - decimals)


def same_number(stored: str, fresh: str, *, roundoff: bool = False) -> bool:
    """Whether two printed numbers are the same value (module docstring)."""
    x, y = float(stored), float(fresh)
    if roundoff:
        return abs(x - y) <= max(ROUNDOFF_FACTOR * min(abs(x), abs(y)), ROUNDOFF_FLOOR) and (
            x * y >= 0 or max(abs(x), abs(y)) <= ROUNDOFF_FLOOR
        )
    whole = all(re.fullmatch(r"[-+]?\d+", t) for t in (stored, fresh))
    if whole:
        return x == y
    return abs(x - y) <= RTOL * max(abs(x), abs(y)) + max(_unit(stored), _unit(fresh))


def same_line(stored: str, fresh: str, *, roundoff: bool = False) -> bool:
    """The same words, and numbers that are the same (:func:`same_number`)."""
    if NUMBER.sub("#", stored) != NUMBER.sub("#", fresh):
        return False
    return all(
        same_number(a, b, roundoff=roundoff)
        for a, b in zip(NUMBER.findall(stored), NUMBER.findall(fresh), strict=True)
    )


def compare(stored, fresh, *, smoke: bool = False) -> list[str]:
    """The differences between the stored and the freshly computed outputs (module docstring)."""
    code = [(c, f) for c, f in zip(stored.cells, fresh.cells, strict=True) if c.cell_type == "code"]
    problems = []
    for k, (old, new) in enumerate(code):
        if "".join(old.source) != "".join(new.source):
            problems.append(f"code cell {k}: the sources differ")
            continue
        t = tags(old)
        if "timing" in t or (smoke and "full-only" in t):
            continue
        roundoff = "roundoff" in t
        a, b = texts(old).splitlines(), texts(new).splitlines()
        if smoke and "subset" in t:
            extra = [y for y in b if not any(same_line(x, y, roundoff=roundoff) for x in a)]
            if extra:
                problems.append(
                    f"code cell {k}: {len(extra)} line(s) of the smoke run are not stored, "
                    f"first: {extra[0]!r}"
                )
            continue
        first = next(
            (
                (x, y)
                for x, y in zip([*a, ""], [*b, ""], strict=False)
                if not same_line(x, y, roundoff=roundoff)
            ),
            None,
        )
        if first is None and len(a) != len(b):
            first = (a[len(b)] if len(a) > len(b) else "", b[len(a)] if len(b) > len(a) else "")
        if first is not None:
            problems.append(
                f"code cell {k}: the output changed; first difference: stored {first[0]!r}, "
                f"fresh {first[1]!r}"
            )
    return problems


def readme_figure(nb) -> bytes | None:
    """The PNG of the (last) figure of the cell tagged ``readme-figure``, if any."""
    png = None
    for cell in nb.cells:
        if cell.cell_type == "code" and "readme-figure" in tags(cell):
            for out in cell.get("outputs", []):
                if "image/png" in out.get("data", {}):
                    png = base64.b64decode(_join(out["data"]["image/png"]))
    return png


def main(argv=None) -> int:
    import nbformat

    p = argparse.ArgumentParser(
        prog="python notebooks/execute.py", description=__doc__.split("\n")[0]
    )
    p.add_argument("names", nargs="*", help="notebooks to execute (default: all)")
    p.add_argument("--check", action="store_true", help="compare with the stored, write nothing")
    p.add_argument(
        "--smoke", action="store_true", help=f"with --check: set {SMOKE}=1 (what the tests run)"
    )
    args = p.parse_args(argv)
    status = 0
    for path in notebooks(args.names):
        print(f"{path.name}: executing ...", flush=True)
        fresh, _ = execute(path, smoke=args.smoke)
        if args.check:
            stored = nbformat.read(path, as_version=4)
            problems = stored_problems(stored) + compare(stored, fresh, smoke=args.smoke)
            for problem in problems:
                print(f"{path.name}: {problem}")
            print(f"{path.name}: {'differs' if problems else 'the same'}")
            status |= bool(problems)
            continue
        nbformat.write(fresh, path)
        print(f"{path.name}: written")
        png = readme_figure(fresh)
        if png is not None:
            FIGURES.mkdir(exist_ok=True)
            target = FIGURES / f"{path.stem}.png"
            target.write_bytes(png)
            print(f"{target.relative_to(HERE.parent)}: written")
    return status


if __name__ == "__main__":
    raise SystemExit(main())
