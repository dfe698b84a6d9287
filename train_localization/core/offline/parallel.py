"""Parallel decoding of a bag: its topics read and decoded in forked worker processes while
the caller fuses (``decode_in_parallel``), with the same items in the same order as a
serial read."""
from __future__ import annotations

import heapq
import multiprocessing
import os
import traceback
from operator import itemgetter
from pathlib import Path
from typing import Callable

from ..bagio import BagReader, topic_counts


# (bag file, decoder, topics read) of the parallel replay running now: set before its worker
# processes are forked, which so inherit it
_PARALLEL_JOB: tuple | None = None
_first = itemgetter(0)
PARALLEL_WINDOW = 1.0   # log time [s] that the workers decode before handing it over


def _decode_topic_windows(mine: list[str], conn) -> None:
    """Worker process: read the bag's messages of every replayed topic in order, decode those of
    ``mine``, and send each window of log time as [(index in the bag's order, topic, log time
    [ns], item), ...]; then None. Every worker reads the same messages, so all send the same
    windows and the indices merge them back into the bag's order."""
    source, decoder, topics = _PARALLEL_JOB
    os.nice(5)   # the fusion in the parent is the critical path: it goes first
    mine = frozenset(mine)
    window_ns = round(PARALLEL_WINDOW * 1e9)
    try:
        with BagReader(source) as reader:
            window, k = [], None
            for i, (topic, typename, t_ns, data) in enumerate(reader.cdr(topics)):
                if t_ns // window_ns != k:
                    if k is not None:
                        conn.send(window)
                        window = []
                    k = t_ns // window_ns
                if topic in mine:
                    window.append((i, topic, t_ns, decoder(topic, typename, data)))
        conn.send(window)
        conn.send(None)
    except BaseException:   # hand the failure to the parent, which raises it
        conn.send(RuntimeError(f"decoding {', '.join(sorted(mine))} failed in its worker process:\n"
                               f"{traceback.format_exc()}"))
    finally:
        conn.close()


def decode_in_parallel(source: Path, decoder: Callable[[str, str, bytes], object], topics: list[str], bar,
                       workers: int | None = None):
    """Decoded (topic, log time [ns], item) of the messages of ``topics`` in the bag ``source``,
    in its order, read and decoded in forked worker processes while the caller fuses.

    The sensors are independent until the fusion, as the live nodes are, so each
    topic goes through its own pipeline, in order, in a worker; the topics are
    shared out over ``workers`` processes (default: one per CPU besides the one the
    fusion runs on here, which is the critical path; forking costs about 10 ms a
    process, more than a small topic's decoding), balanced by their message
    counts. Each worker streams the bag itself (nothing is held in memory beyond a
    window) and hands over one window of log time after the other, so the caller
    fuses window k while window k + 1 is decoded. The items come in the bag's
    order, as in the serial replay, so the result is the same.
    """
    global _PARALLEL_JOB
    try:
        counts = topic_counts(source)
    except Exception:   # a summary without message statistics: the topics shared out by number
        counts = {}
    weight = {t: counts.get(t, 1) for t in topics}
    topics = [t for t in topics if weight[t]]
    if not topics:
        return
    workers = workers or max((os.cpu_count() or 1) - 1, 1)
    groups: list[list[str]] = [[] for _ in range(min(workers, len(topics)))]
    load = [0] * len(groups)
    for topic in sorted(topics, key=weight.get, reverse=True):   # largest first, to the least loaded
        i = load.index(min(load))
        groups[i].append(topic)
        load[i] += weight[topic]
    ctx = multiprocessing.get_context("fork")
    conns, procs = [], []
    _PARALLEL_JOB = (source, decoder, topics)
    try:
        for mine in groups:
            receive, send = ctx.Pipe(duplex=False)
            proc = ctx.Process(target=_decode_topic_windows, args=(mine, send), daemon=True,
                               name=f"replay {mine[0]}")
            proc.start()
            send.close()    # the worker holds it: a worker that dies ends the parent's recv
            conns.append(receive)
            procs.append(proc)
    finally:
        _PARALLEL_JOB = None
    try:
        while True:
            windows = []
            for conn in conns:
                got = conn.recv()
                if isinstance(got, BaseException):
                    raise got
                windows.append(got)
            if windows[0] is None:
                break
            for _, topic, t_ns, item in heapq.merge(*windows, key=_first):
                yield topic, t_ns, item
            if bar:
                bar.update(sum(map(len, windows)))
    finally:
        for proc in procs:
            if proc.is_alive():
                # SIGKILL: a worker may be blocked writing to a full pipe, and may have
                # inherited a SIGTERM handler that does not exit (rclpy.init installs one)
                proc.kill()
            proc.join()
        for conn in conns:
            conn.close()


def can_fork() -> bool:
    """Whether parallel replay is available here (it forks worker processes)."""
    return "fork" in multiprocessing.get_all_start_methods()
