"""The DDS environment of the project's own runs (demo, fuzz, test workers, launch files): the
discovery range, and one free ROS_DOMAIN_ID per run, held for as long as the run lives.

A random pick alone lets two runs on one host share a domain (two pytest workers each running
a demo graph did, and each recorded the other's messages). A lease is an exclusive ``flock`` on
a per-domain file in the temporary directory: every run of this project on the host skips a
domain another one holds, and the kernel drops the lock when the holder exits, however it
exits. A run that starts node processes passes them the lock (tl_demo: ``pass_fds``): it is
held then until the last of them has exited too, even if the run itself is killed. Programs
that are not this project do not take the locks; the ranges below keep clear of ROS 2's
default domain 0.
"""
from __future__ import annotations

import fcntl
import os
import random
import tempfile
from pathlib import Path
from typing import IO, Iterable, NamedTuple

LOCK_DIR = Path(tempfile.gettempdir()) / "train_localization-domains"


def discovery_range(environ) -> str:
    """The caller's ROS_AUTOMATIC_DISCOVERY_RANGE; unset or empty (rmw takes an empty value for
    its default, the subnet): LOCALHOST."""
    return environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE") or "LOCALHOST"


def node_env(domain: int | None) -> dict:
    """The environment of node processes a tool starts: the caller's, with the discovery range
    (``discovery_range``), ``domain`` as ROS_DOMAIN_ID (None: the caller's), Fast DDS unless the
    caller chose an rmw, and unbuffered Python output (their logs)."""
    env = dict(os.environ)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = discovery_range(env)
    if domain is not None:
        env["ROS_DOMAIN_ID"] = str(domain)
    env.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
    env["PYTHONUNBUFFERED"] = "1"
    return env


class DomainLease(NamedTuple):
    """A ROS_DOMAIN_ID held by this process: ``handle`` keeps the lock; close it to free it."""

    domain: int
    handle: IO

    def release(self) -> None:
        """Free the domain for other runs (also done by the kernel when the process exits)."""
        self.handle.close()


def _try_lock(domain: int) -> IO | None:
    """The open, exclusively locked lock file of ``domain``, or None when another run holds it
    (or the file cannot be opened by this user)."""
    try:
        handle = open(LOCK_DIR / f"{domain}.lock", "a")   # close-on-exec: a child holds it only if passed it
    except OSError:
        return None
    try:
        fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        handle.close()
        return None
    return handle


def lease(low: int, high: int, avoid: Iterable[int] = ()) -> DomainLease:
    """A free ROS_DOMAIN_ID in ``low..high`` (inclusive), not in ``avoid``, tried in random
    order and held by this process until released or the process exits. Raises RuntimeError
    when every domain of the range is held."""
    if not 0 <= low <= high <= 232:
        raise ValueError(f"a ROS_DOMAIN_ID range is within 0..232, got {low}..{high}")
    LOCK_DIR.mkdir(parents=True, exist_ok=True)
    try:
        os.chmod(LOCK_DIR, 0o1777)   # shared by every user of the host, like /tmp itself
    except OSError:
        pass
    skipped = set(avoid)
    candidates = [d for d in range(low, high + 1) if d not in skipped]
    random.SystemRandom().shuffle(candidates)
    for domain in candidates:
        handle = _try_lock(domain)
        if handle is not None:
            return DomainLease(domain, handle)
    raise RuntimeError(f"no free ROS_DOMAIN_ID in {low}..{high}: every one is held by another "
                       f"run of this project (locks in {LOCK_DIR})")
