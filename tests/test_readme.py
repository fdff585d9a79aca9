"""The README's test command is the one CI runs, verbatim."""

from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MARKER = "# set up and run the tests"


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
