"""``python -m cardiosoft.sweep``: the same command as ``cardiosoft sweep``."""

import sys

from cardiosoft._cli import prepare_process

if __name__ == "__main__":
    # Before JAX starts its backend: the XLA host devices this process shards chunks over.
    prepare_process("sweep", sys.argv[1:])
    # The library's main (cardiosoft.sweep.cli), so that Dask pickles the chunk solve by
    # reference to cardiosoft.sweep.chunk, not by value from __main__.
    from cardiosoft.sweep.cli import main

    raise SystemExit(main())
