"""The published mode of the filter (TrainState.mode): its meaning is in interval.py."""
from __future__ import annotations

from enum import IntEnum


class Mode(IntEnum):
    """TrainState.mode (train_localization_msgs/TrainState)."""

    INITIALISING = 0
    NOMINAL = 1
    DEGRADED = 2
    LOST = 3
