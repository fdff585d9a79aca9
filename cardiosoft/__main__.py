"""``python -m cardiosoft``: the ``cardiosoft`` command (:mod:`cardiosoft.cli`)."""

from cardiosoft.cli import run

if __name__ == "__main__":
    raise SystemExit(run())
