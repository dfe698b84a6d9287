"""A scenario's vehicle: its kind, length, axles, wheels and pantographs.

Apart from core/scenario.py for the same reason as core/truth.py: the sensor simulators and
the wayside use it, and the scenario validates their settings.
"""
from __future__ import annotations

from dataclasses import dataclass


@dataclass
class Vehicle:
    """Vehicle type, length [m] and axle offsets behind the front [m] (none for maglev); the
    raised pantographs' offsets behind the front [m] and whether a roof bus joins them (the
    catenary of a changeover section, core/wayside/catenary.py)."""

    kind: str = "conventional"
    length: float = 200.0
    axles: tuple[float, ...] = ()
    wheel_diameter: float = 0.92  # nominal [m]
    pantographs: tuple[float, ...] = ()
    roof_bus: bool = False
