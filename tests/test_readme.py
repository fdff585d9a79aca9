"""The README and the documentation site's pages against the code: the README's test command
is the one CI runs, verbatim, the README stays a front door (at most 150 lines), and every
command and public name the README and the pages of ``docs/`` show still works (issue 25: a
walk through the README; issue 42: the pages it moved to).

The commands are checked cheaply: each command line of the README and of every ``docs/**/*.md``
page (their ``bash`` blocks and their inline ``python -m cardiosoft...`` / ``cardiosoft ...``)
is parsed by that command's own parser
(every option the README uses exists and takes the values it is given), other scripts and
modules it names exist, and the ``cardiosoft`` command itself runs: ``--version``, ``--help``,
and ``cardiosoft geometry`` printing what ``python -m cardiosoft.geometry`` prints.
"""

import importlib
import importlib.util
import re
import shlex
import subprocess
import sys
from importlib import metadata
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MARKER = "# set up and run the tests"
README = (ROOT / "README.md").read_text()
README_MAX_LINES = 150  # issue 42: the README is the front door; the long results live in docs/
# The files the walk reads: the README and every page of the site (docs/notebooks/index.md is
# a link to notebooks/README.md, which is walked through it).
WALKED = ["README.md", *sorted(str(p.relative_to(ROOT)) for p in (ROOT / "docs").rglob("*.md"))]


def text_of(name: str) -> str:
    return (ROOT / name).read_text(encoding="utf-8")


def readme_test_command() -> str:
    text = (ROOT / "README.md").read_text()
    start = text.index("```bash\n") + len("```bash\n")
    block = text[start : text.index("```", start)].splitlines()
    assert MARKER in block, f"{MARKER!r} not in the README's first bash block"
    command = block[block.index(MARKER) + 1]
    assert command.strip() and not command.lstrip().startswith("#"), command
    return command


def test_readme_test_command_is_run_by_ci_verbatim():
    command = readme_test_command()
    assert "pytest" in command
    ci_lines = (ROOT / ".ci" / "run").read_text().splitlines()
    # a whole, uncommented line of the CI script (its exit status captured for the exit-5
    # check), not a fragment of one or a comment
    assert any(line in (command, command + " || status=$?") for line in ci_lines), (
        f"README test command not found as a line of .ci/run: {command}"
    )


def test_the_readme_is_a_front_door():
    lines = README.count("\n") + (not README.endswith("\n"))  # wc -l, and a last line unended
    assert lines <= README_MAX_LINES, (
        f"README.md has {lines} lines, at most {README_MAX_LINES}: move the long parts to docs/"
    )


# ------------------------------------------------------------------------------ the walk


def readme_command_lines(text: str = README) -> list[str]:
    """Every command line of a Markdown file (the README by default): the lines of its bash
    blocks (comments cut, each ``&&`` part on its own) and its inline code spans that start
    like a command."""
    lines = []
    for block in re.findall(r"```bash\n(.*?)```", text, flags=re.S):
        for line in block.splitlines():
            line = line.split(" #")[0].strip()
            if line and not line.startswith("#"):
                lines += [part.strip() for part in line.split("&&")]
    for span in re.findall(r"`([^`\n]+)`", text):
        if re.match(r"(python|cardiosoft) ", span):
            lines.append(span)
    return lines


def tool_and_arguments(line: str):
    """(the cardiosoft subcommand, its arguments) of a command line, or None for another."""
    words = shlex.split(line)
    if words[0] == "cardiosoft" and len(words) > 1 and not words[1].startswith("-"):
        return words[1], words[2:]
    for i, word in enumerate(words[:-1]):
        if word == "-m" and words[i + 1].startswith("cardiosoft."):
            return words[i + 1].removeprefix("cardiosoft."), words[i + 2 :]
    return None


TOOL_LINES = [
    pytest.param(line, id=f"{name}: {line}")
    for name in WALKED
    for line in readme_command_lines(text_of(name))
    if tool_and_arguments(line)
]


def test_the_readme_shows_every_command():
    """The README and the pages together show every subcommand."""
    tools = {tool_and_arguments(p.values[0])[0] for p in TOOL_LINES}
    tools = {t for t in tools if not t.isupper()}  # placeholders: "python -m cardiosoft.X"
    from cardiosoft.cli import COMMANDS

    assert set(COMMANDS) <= tools, set(COMMANDS) - tools
    assert {"simulate", "design", "sweep", "stress", "geometry"} <= set(COMMANDS)


@pytest.mark.parametrize("line", TOOL_LINES)
def test_every_command_line_of_the_readme_parses(line):
    """The command's own parser accepts the README's and the pages' arguments (a placeholder
    ``...`` stands for any arguments, a command in capitals, ``X`` or ``COMMAND``, for any
    command, and a command named without arguments for the command: then each option shown
    must exist)."""
    from cardiosoft.cli import COMMANDS

    tool, argv = tool_and_arguments(line)
    if tool.isupper():  # a placeholder for any command: X, COMMAND
        return
    assert tool in COMMANDS, line
    parser = importlib.import_module(COMMANDS[tool][0]).parser(f"cardiosoft {tool}")
    if "..." in argv or not argv:
        known = {o for action in parser._actions for o in action.option_strings}
        assert {a for a in argv if a.startswith("--")} <= known, line
        return
    parser.parse_args(argv)  # exits with status 2 (and fails this test) on a bad argument


def other_commands_exist(text: str) -> int:
    """Checks ``python -m fit...``, ``python benchmarks/x.py``, ``python notebooks/execute.py``
    of a file exist; how many it checked."""
    others = [line for line in readme_command_lines(text) if not tool_and_arguments(line)]
    seen = 0
    for line in others:
        words = shlex.split(line)
        if "-m" in words and words[0].endswith("python"):
            module = words[words.index("-m") + 1]
            if module in ("venv", "pytest", "cardiosoft"):
                continue
            assert importlib.util.find_spec(module) is not None, line
            seen += 1
        elif words[0].endswith("python") and words[1].endswith(".py"):
            assert (ROOT / words[1]).is_file(), line
            seen += 1
    return seen


@pytest.mark.parametrize("name", WALKED)
def test_other_commands_of_the_readme_exist(name):
    other_commands_exist(text_of(name))


def test_the_walk_sees_other_commands():
    assert sum(other_commands_exist(text_of(name)) for name in WALKED) >= 3


def public_names(text: str = README) -> set[str]:
    """The dotted names of cardiosoft a file names (``cardiosoft.x.y``, ``cs.x``)."""
    names = set(re.findall(r"`(cardiosoft(?:\.[A-Za-z_][A-Za-z0-9_]*)+)", text))
    names |= {f"cardiosoft.{n}" for n in re.findall(r"\bcs\.([A-Za-z_][A-Za-z0-9_]*)", text)}
    for module, imported in re.findall(r"from (cardiosoft[.\w]*) import ([\w, ]+)", text):
        names |= {f"{module}.{n.strip()}" for n in imported.split(",")}
    return names


NAMED = sorted({(name, file) for file in WALKED for name in public_names(text_of(file))})


@pytest.mark.parametrize("name", [pytest.param(name, id=f"{file}: {name}") for name, file in NAMED])
def test_every_public_name_of_the_readme_exists(name):
    parts = name.split(".")
    for n in range(len(parts), 0, -1):  # the longest prefix that is a module
        try:
            obj = importlib.import_module(".".join(parts[:n]))
        except ModuleNotFoundError:
            continue
        for attr in parts[n:]:
            obj = getattr(obj, attr)
        return
    raise AssertionError(name)


def cardiosoft_command(*args):
    script = Path(sys.executable).with_name("cardiosoft")
    if not script.exists():
        pytest.skip(f"no cardiosoft command beside {sys.executable} (pip install -e .)")
    return subprocess.run(
        [str(script), *args], capture_output=True, text=True, timeout=300, cwd=ROOT
    )


def test_the_cardiosoft_command_tells_its_version_and_its_commands():
    done = cardiosoft_command("--version")
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["cardiosoft", metadata.version("cardiosoft")]
    done = cardiosoft_command("--help")
    assert done.returncode == 0 and "simulate" in done.stdout and "exit status" in done.stdout
    done = cardiosoft_command("nope")
    assert done.returncode == 2 and done.stderr.count("\n") == 1 and done.stdout == ""


def test_cardiosoft_geometry_is_python_m_cardiosoft_geometry():
    mine = cardiosoft_command("geometry")
    theirs = subprocess.run(
        [sys.executable, "-m", "cardiosoft.geometry"],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=ROOT,
    )
    assert mine.returncode == theirs.returncode == 0, mine.stderr + theirs.stderr
    assert mine.stdout == theirs.stdout and "Apex translation" in mine.stdout


@pytest.mark.parametrize("tool", ["simulate", "design", "sweep", "stress", "geometry"])
def test_every_subcommand_says_its_exit_status(tool, capsys):
    from cardiosoft.cli import main

    with pytest.raises(SystemExit) as done:
        main([tool, "--help"])
    assert done.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith(f"usage: cardiosoft {tool}")
    assert "exit status: 0" in " ".join(out.split())
