"""``python -m cardiosoft.credibility``: the same command as ``cardiosoft credibility``."""

import sys

from cardiosoft._cli import prepare_process
from cardiosoft.credibility.cli import main

if __name__ == "__main__":
    prepare_process("credibility", sys.argv[1:])
    raise SystemExit(main())
