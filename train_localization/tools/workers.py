"""Independent jobs on local worker processes or a dask.distributed scheduler: the campaign's
runs (tools/campaign.py) and a fleet's bags (tools/replay.py)."""
from __future__ import annotations

import os
from typing import Callable


def run_jobs(fn: Callable, jobs: list[tuple], workers: int | None, scheduler: str | None,
             on_result: Callable[[tuple, object], None], on_lost: Callable[[tuple, BaseException], None]) -> None:
    """``fn(*job)`` of every job, in parallel; ``on_result(job, result)`` as each completes (in
    completion order), ``on_lost(job, exception)`` for one that raised or whose worker died.

    ``scheduler``: None = a local process pool of ``workers`` processes (default: the CPU count);
    "local" = a dask LocalCluster on 127.0.0.1 with ``workers`` single-threaded worker processes;
    any other string = the address of a running dask.distributed scheduler (tcp://HOST:PORT; its
    workers must import this package).
    """
    workers = workers or os.cpu_count() or 1
    if scheduler is None:
        from concurrent.futures import ProcessPoolExecutor, as_completed
        with ProcessPoolExecutor(max_workers=workers) as pool:
            futures = {pool.submit(fn, *job): job for job in jobs}
            for fut in as_completed(futures):
                try:
                    result = fut.result()
                except Exception as exc:
                    on_lost(futures[fut], exc)
                    continue
                on_result(futures[fut], result)
        return
    from dask.distributed import Client, LocalCluster, as_completed
    cluster = None
    if scheduler == "local":
        cluster = LocalCluster(host="127.0.0.1", n_workers=workers, threads_per_worker=1, processes=True,
                               dashboard_address=None)
        client = Client(cluster)
    else:
        client = Client(scheduler)
    try:
        futures = client.map(fn, *zip(*jobs), pure=False) if jobs else []
        keys = {fut.key: job for fut, job in zip(futures, jobs)}
        for fut in as_completed(futures):
            try:
                result = fut.result()
            except Exception as exc:
                on_lost(keys[fut.key], exc)
                continue
            on_result(keys[fut.key], result)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
