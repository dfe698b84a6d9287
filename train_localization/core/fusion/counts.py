"""What the filter counted of its readings: the integrity events (``counters()``' ``integrity``),
the readings accepted and gated per sensor, and when each sensor was last accepted (or counts
as in use since: a fix found it right, its exclusion ended, the operator's reset).

The one writer of ``Bookkeeping.events``, ``accepted``, ``gated`` and ``last_accepted``: the
policies and stages count through these functions (copy-on-write, as bookkeeping.py says)."""
from __future__ import annotations

from .bookkeeping import Bookkeeping, incremented


def event(aux: Bookkeeping, name: str) -> None:
    """Integrity event ``name`` happened once more."""
    aux.events = incremented(aux.events, name)


def gated(aux: Bookkeeping, key: str) -> None:
    """A reading of ``key`` (a sensor, or ``sensor/slip``, ``sensor/suspended``: why) not applied."""
    aux.gated = incremented(aux.gated, key)


def accepted(aux: Bookkeeping, cls: str, stamp: float) -> None:
    """A reading of sensor ``cls`` at ``stamp`` [s] taken by the filter."""
    aux.accepted = incremented(aux.accepted, cls)
    in_use_from(aux, (cls,), stamp)


def in_use_from(aux: Bookkeeping, sensors, stamp: float) -> None:
    """``sensors`` count as accepted at ``stamp`` [s] (a reading taken, or their exclusion ended)."""
    aux.last_accepted = {**aux.last_accepted, **{c: stamp for c in sensors}}
