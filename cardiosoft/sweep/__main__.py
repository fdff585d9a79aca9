"""``python -m cardiosoft.sweep``: design-space maps (see :mod:`cardiosoft.sweep`)."""

import os
import sys

from cardiosoft.sweep import main

if __name__ == "__main__":
    # JAX gives a CPU one device, and a batch on one device runs on one core. As many XLA host
    # devices as cores let solve_beats shard each chunk over all of them (measured on 2 cores:
    # benchmarks/sweep_throughput.py, section 4). Set here, before JAX starts its backend, so
    # that it stays with this process; not with --workers or --scheduler, whose worker
    # processes share the cores among themselves; a device count of the user's own is kept.
    _flags = os.environ.get("XLA_FLAGS", "")
    if "xla_force_host_platform_device_count" not in _flags and not {
        "--workers",
        "--scheduler",
    } & {a.split("=")[0] for a in sys.argv[1:]}:
        _count = f"--xla_force_host_platform_device_count={os.cpu_count() or 1}"
        os.environ["XLA_FLAGS"] = f"{_flags} {_count}".strip()
    # The library's main (cardiosoft.sweep), so that Dask pickles its functions by reference to
    # cardiosoft.sweep, not by value from __main__.
    from cardiosoft._cli import use_compile_cache

    use_compile_cache()  # the next process loads what this one compiles
    raise SystemExit(main())
