"""``python -m cardiosoft.geometry``: the same command as ``cardiosoft geometry`` (the Fig. 7(a)
table and figure)."""

from cardiosoft.geometry.cli import main

if __name__ == "__main__":
    raise SystemExit(main())
