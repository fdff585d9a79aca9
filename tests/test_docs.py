"""The documentation site (issue 42): ``mkdocs build --strict`` passes from the repository root,
every public name has its entry in the API reference, and every stored notebook is a page.

The strict build is the check of the pages themselves: mkdocs fails it on a broken link or
anchor, on a page that is not in the nav (``validation`` in ``mkdocs.yml``), and mkdocstrings on
a ``:::`` entry it cannot resolve. Its run is about 10 s on 2 cores, most of it rendering the
notebooks (mkdocs-jupyter, not executing them).
"""

import importlib
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
API_PAGES = [DOCS / "api.md"]
"""The pages of the API reference: where every public name needs its ``:::`` entry."""
PACKAGES = ["cardiosoft", "cardiosoft.network"]
"""The packages whose ``__all__`` is the public API."""


def test_the_site_builds_strict(tmp_path):
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}  # Material's banner about its successor
    done = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=600,
        env=env,
    )
    assert done.returncode == 0, f"mkdocs build --strict failed:\n{done.stdout}\n{done.stderr}"
    assert (tmp_path / "index.html").is_file()
    assert (tmp_path / "notebooks" / "figures" / "fig10_bench.png").is_file()


def api_entries() -> set[str]:
    """The objects the API pages document (``::: cardiosoft.x.y`` lines)."""
    text = "\n".join(page.read_text(encoding="utf-8") for page in API_PAGES)
    return set(re.findall(r"^::: *([\w.]+)\s*$", text, flags=re.M))


def documented_as(package: str, name: str) -> set[str]:
    """The entries that document a public name: under its package, or under the module that
    defines it (where the package's lazy name does not resolve statically)."""
    module = importlib.import_module(package)
    where = {f"{package}.{name}"}
    defined_in = getattr(module, "PUBLIC", {}).get(name)
    if defined_in:
        where.add(f"{defined_in}.{getattr(module, 'RENAMED', {}).get(name, name)}")
    return where


@pytest.mark.parametrize(
    ("package", "name"),
    [(p, n) for p in PACKAGES for n in importlib.import_module(p).__all__],
)
def test_every_public_name_is_in_the_api_reference(package, name):
    entries = api_entries()
    assert documented_as(package, name) & entries, (
        f"{package}.{name} is public ({package}.__all__) but no API page has "
        f"'::: {package}.{name}' ({', '.join(p.name for p in API_PAGES)})"
    )


def test_every_notebook_is_a_page_and_stored_once():
    """docs/notebooks/NAME.ipynb is a relative link to notebooks/NAME.ipynb for each stored
    notebook (one copy of each; the site renders it), and nothing else sits there."""
    stored = sorted(p.name for p in (ROOT / "notebooks").glob("*.ipynb"))
    assert stored, "no notebooks found"
    linked = sorted(p.name for p in (DOCS / "notebooks").glob("*.ipynb"))
    assert linked == stored, "add a link: ln -s ../../notebooks/NAME.ipynb docs/notebooks/"
    for name in linked:
        page = DOCS / "notebooks" / name
        assert page.is_symlink() and not Path(os.readlink(page)).is_absolute(), name
        assert page.resolve() == (ROOT / "notebooks" / name).resolve(), name
    listing = DOCS / "notebooks" / "index.md"
    assert listing.resolve() == (ROOT / "notebooks" / "README.md").resolve()
