"""The base of the filter's policy components (episodes, arbitration, fixes, ...)."""
from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from .filter import TrainFilter


class Component:
    """A part of the filter (TrainFilter), which builds it with itself as the context: the
    component reads and updates the filter's EKF state and bookkeeping, config, layout and
    models through ``f``."""

    def __init__(self, f: TrainFilter):
        self.f = f
