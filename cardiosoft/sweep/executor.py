"""Where the chunks of a sweep run: in this process, or as tasks of Dask's distributed
scheduler (a local cluster of worker processes, or a running cluster at an address)."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

from cardiosoft.sweep import chunk as chunks
from cardiosoft.sweep.chunk import failed_result

__all__ = ["executor", "run_dask", "run_here", "window"]


def run_here(tasks) -> Iterator[tuple[int, dict]]:
    """Chunks one after the other in this process: (index, result) each."""
    for task in tasks:
        yield task.index, chunks.solve_chunk(task)  # looked up now: tests replace it


def run_dask(client, tasks, window: int) -> Iterator[tuple[int, dict]]:
    """Chunks as Dask tasks, at most ``window`` in flight (the client holds no more)."""
    from distributed import as_completed

    tasks = iter(tasks)
    pending = {}

    def submit():
        task = next(tasks, None)
        if task is None:
            return None
        future = client.submit(
            chunks.solve_chunk, task, pure=False, key=f"cardiosoft-chunk-{task.index}"
        )
        pending[future.key] = task
        return future

    futures = [f for f in (submit() for _ in range(window)) if f is not None]
    queue = as_completed(futures, loop=client.loop)
    for future in queue:
        task = pending.pop(future.key)
        try:
            result = future.result()
        except Exception as err:  # a lost worker fails its chunk, not the sweep
            message = f"{type(err).__name__}: {err}".splitlines()[0]
            result = failed_result(task.valid, message, task.metrics, task.draws)
        future.release()
        yield task.index, result
        nxt = submit()
        if nxt is not None:
            queue.add(nxt)


@contextlib.contextmanager
def executor(workers, scheduler, client):
    """(a function running tasks, how it is described) for the chosen place."""
    if client is not None:
        yield (lambda tasks: run_dask(client, tasks, window(client))), "a Dask client"
        return
    if workers is None and scheduler is None:
        import jax

        devices = jax.devices()
        yield run_here, f"this process on {len(devices)} {devices[0].platform.upper()} device(s)"
        return
    import logging

    from distributed import Client, LocalCluster

    if scheduler is not None:
        try:
            own = Client(scheduler, timeout="10s", set_as_default=False)
        except (OSError, TimeoutError, ValueError) as err:
            raise ValueError(
                f"--scheduler {scheduler}: cannot reach a Dask scheduler there ({err})"
            ) from None
        where = f"the Dask scheduler at {scheduler}"
        cluster = None
    else:
        cluster = LocalCluster(
            n_workers=workers,
            threads_per_worker=1,
            processes=True,
            dashboard_address=None,
            silence_logs=logging.ERROR,
        )
        own = Client(cluster, set_as_default=False)
        where = f"a local Dask cluster of {workers} worker processes"
    try:
        yield (lambda tasks: run_dask(own, tasks, window(own))), where
    finally:
        own.close()
        if cluster is not None:
            cluster.close()


def window(client) -> int:
    """Chunks in flight at once: twice the cluster's threads, at least 4."""
    threads = sum(client.nthreads().values()) or 1
    return max(4, 2 * threads)
