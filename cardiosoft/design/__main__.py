"""``python -m cardiosoft.design``: the same command as ``cardiosoft design``."""

import sys

from cardiosoft._cli import prepare_process
from cardiosoft.design.cli import main

if __name__ == "__main__":
    prepare_process("design", sys.argv[1:])
    raise SystemExit(main())
