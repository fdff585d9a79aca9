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
displays; not images, not stderr) must be the same after a fresh execution, to the last printed
digit. Cell tags (``metadata.tags``) set exceptions:

- ``timing``: wall-clock times, different on every run; never compared;
- ``subset``: under :data:`SMOKE` (a smaller computation, for the tests) every line the smoke
  run prints must be one of the stored lines; without it, compared whole;
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
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
FIGURES = HERE / "figures"
SMOKE = "CARDIOSOFT_NOTEBOOK_SMOKE"
"""Environment variable: set to 1, ``notebooks/accuracy.ipynb`` computes a subset (the tests)."""
TIMEOUT = 3600  # s, per cell
TEXT_TYPES = ("text/plain", "text/markdown")


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
        a, b = texts(old), texts(new)
        if smoke and "subset" in t:
            lines = set(a.splitlines())
            extra = [line for line in b.splitlines() if line not in lines]
            if extra:
                problems.append(
                    f"code cell {k}: {len(extra)} line(s) of the smoke run are not stored, "
                    f"first: {extra[0]!r}"
                )
        elif a != b:
            first = next(
                (
                    (x, y)
                    for x, y in zip([*a.splitlines(), ""], [*b.splitlines(), ""], strict=False)
                    if x != y
                ),
                ("", ""),
            )
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
