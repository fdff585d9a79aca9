"""``python -m cardiosoft.stress``: the same command as ``cardiosoft stress``."""

import sys

from cardiosoft._cli import prepare_process
from cardiosoft.stress.cli import main

if __name__ == "__main__":
    prepare_process("stress", sys.argv[1:])
    raise SystemExit(main())
