"""A regular (non-editable) install works without the repository: the wheel carries the shipped
surrogate and the paper's data, and ``python -m cardiosoft.simulate --compare-paper`` finds them
from any working directory.

The wheel is built offline with this environment's setuptools and installed, without its
dependencies, into a fresh virtual environment that borrows them from this one through a
``.pth`` file: nothing is downloaded.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

from cardiosoft.pump import DEFAULT_ARTIFACT

ROOT = Path(__file__).resolve().parent.parent
# what pyproject.toml builds the distribution from
SOURCES = ("pyproject.toml", "README.md", "cardiosoft", "surrogates", "fit/data")

CHECK = """
import cardiosoft
from cardiosoft import datasets, pump
print(cardiosoft.__file__)
print(datasets.default_root())
print(pump.load_card()["weights_file"])
print(len(datasets.load_paper_data().fig10_bench))
"""


def _run(args, **kwargs):
    out = subprocess.run(args, capture_output=True, text=True, timeout=600, **kwargs)
    assert out.returncode == 0, f"{args}\n{out.stdout}\n{out.stderr}"
    return out


def test_wheel_installs_and_simulate_compares_with_the_paper(tmp_path):
    # build from a copy, so that no build/ folder or stale file of the checkout gets in
    src = tmp_path / "src"
    for name in SOURCES:
        if (ROOT / name).is_dir():
            shutil.copytree(ROOT / name, src / name, ignore=shutil.ignore_patterns("__pycache__"))
        else:
            (src / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(ROOT / name, src / name)
    pip = [sys.executable, "-m", "pip", "--disable-pip-version-check", "--no-input"]
    dist = tmp_path / "dist"
    _run([*pip, "wheel", "--no-deps", "--no-build-isolation", "--no-index", "-w", dist, src])
    (wheel,) = dist.glob("cardiosoft-*.whl")

    fresh = tmp_path / "fresh"
    _run([sys.executable, "-m", "venv", str(fresh)])
    python = fresh / "bin" / "python"
    purelib = "import sysconfig; print(sysconfig.get_paths()['purelib'])"
    site = Path(_run([python, "-c", purelib]).stdout.strip())
    # the dependencies (jax, diffrax, ...) come from this environment; a .pth file in a folder
    # added this way is not read, so the editable install of the checkout stays out
    ours = [p for p in sys.path if Path(p).name in ("site-packages", "dist-packages")]
    (site / "cardiosoft_test_dependencies.pth").write_text("\n".join(ours) + "\n")
    _run([python, *pip[1:], "install", "--no-deps", "--no-index", wheel])

    work = tmp_path / "work"
    work.mkdir()
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    file, root, weights, rows = _run([python, "-c", CHECK], cwd=work, env=env).stdout.split()
    assert Path(file).is_relative_to(site / "cardiosoft"), file
    assert Path(root) == site / "cardiosoft" / "_paper_data"
    assert (weights, rows) == (f"{DEFAULT_ARTIFACT}.eqx", "3")

    # a fresh machine's cache; the wheel ships the main job's programs: copied, not traced
    # (cardiosoft.program_store.SHIPPED; JAX's log names an export's trace <function>_exported)
    env.update(CARDIOSOFT_COMPILE_CACHE=str(tmp_path / "cache"), JAX_LOG_COMPILES="1")
    out = subprocess.run(
        [python, "-m", "cardiosoft.simulate", "--bpm", "30", "--compare-paper"],
        capture_output=True,
        text=True,
        timeout=600,
        cwd=work,
        env=env,
    )
    assert out.returncode == 0, out.stderr
    assert "found in sys.modules" not in out.stderr
    assert "_exported for jit" not in out.stderr, "the wheel's shipped programs were not used"
    assert len(list((tmp_path / "cache" / "programs").glob("*.jaxprogram"))) == 2
    assert len(re.findall(r"^\s+paper\s+\d", out.stdout, flags=re.MULTILINE)) == 3, out.stdout
