"""A track's gradient profile: the rise of the track along its chainage (docs/nodes.md,
"Accelerometer").

Given as the ``gradient`` block of a track file, in the form of a line's gradient table (as
ETCS's gradient profile, packet 21, gives it: a constant gradient from each change point to the
next)::

    gradient:
      vertical_curve_radius: 10000.0   # [m], optional; 0 (default): the gradient steps
      profile:
        - {position: 0.0, gradient: 0.0}       # [per mille], + rising towards increasing chainage
        - {position: 1200.0, gradient: 12.5}   # from 1200 m to the next change point
        - {position: 3400.0, gradient: -8.0}

Before the first change point the first gradient holds, after the last the last. A vertical
curve of radius R joins two gradients i1, i2 (fractions): over R |i2 - i1| centred on the change
point the gradient changes linearly (a parabolic curve in height). A track without the block is
level. Refused (GradientError, one line): an entry without ``position`` or ``gradient``, change
points not strictly increasing or off the track, a gradient steeper than MAX_GRADIENT, vertical
curves that overlap.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

MAX_GRADIENT = 250.0   # [per mille] the steepest rack railways; no adhesion line comes near


class GradientError(ValueError):
    """A gradient block that cannot be used, with the reason."""


@dataclass(frozen=True)
class GradientProfile:
    """Piecewise-linear gradient [1, rise / run] against chainage [m]: ``chainages`` (non-
    decreasing) and ``gradients`` the break points of np.interp."""

    chainages: np.ndarray
    gradients: np.ndarray

    def at(self, chainage):
        """Gradient [1] (tan of the track's inclination) at chainages [m] (number or array)."""
        out = np.interp(np.asarray(chainage, dtype=float), self.chainages, self.gradients)
        return out if out.ndim else float(out)

    def span(self, lo: float, hi: float) -> tuple[float, float]:
        """(least, greatest) gradient [1] over chainages lo .. hi [m]."""
        inside = self.gradients[(self.chainages > lo) & (self.chainages < hi)]
        ends = (self.at(lo), self.at(hi))
        return float(min(*ends, *inside)), float(max(*ends, *inside))


def along_track_gravity(gradient, g: float):
    """Component of gravity along a track of ``gradient`` [1] (number or array) [m/s^2]:
    g sin(atan(i)), + where the track rises towards increasing chainage."""
    i = np.asarray(gradient, dtype=float)
    out = g * i / np.sqrt(1.0 + i * i)
    return out if out.ndim else float(out)


def _number(value, name: str) -> float:
    """``value`` as a float; GradientError naming ``name`` if it is none."""
    try:
        return float(value)
    except (TypeError, ValueError):
        raise GradientError(f"gradient block: {name} {value!r} is not a number") from None


def parse(block, length: float) -> GradientProfile | None:
    """The profile of a track's ``gradient`` block (module docstring) on a track of ``length``
    [m]; None without one. GradientError names the first bad entry."""
    if block is None:
        return None
    if not isinstance(block, dict) or not isinstance(block.get("profile"), list) or not block["profile"]:
        raise GradientError(f"gradient block must be a mapping with a non-empty 'profile' list, not {block!r}")
    radius = _number(block.get("vertical_curve_radius", 0.0), "vertical_curve_radius")
    if not (math.isfinite(radius) and radius >= 0.0):
        raise GradientError(f"gradient vertical_curve_radius {radius!r} must be a number >= 0 [m]")
    points, grades = [], []
    for entry in block["profile"]:
        if not isinstance(entry, dict) or "position" not in entry or "gradient" not in entry:
            raise GradientError(f"gradient entry {entry!r} needs 'position' [m] and 'gradient' [per mille]")
        s, i = _number(entry["position"], "position"), _number(entry["gradient"], "gradient")
        if not (math.isfinite(s) and 0.0 <= s <= length):
            raise GradientError(f"gradient change point {s!r} m is off the track (0..{length} m)")
        if not (math.isfinite(i) and abs(i) <= MAX_GRADIENT):
            raise GradientError(f"gradient {i!r} per mille at {s} m is beyond +-{MAX_GRADIENT:g} per mille")
        if points and s <= points[-1]:
            raise GradientError(f"gradient change points must increase: {s} m after {points[-1]} m")
        points.append(s)
        grades.append(i / 1000.0)
    xs, ys = [points[0]], [grades[0]]
    for k in range(1, len(points)):
        # a step is a ramp of a micrometre: np.interp needs increasing break points
        half = max(0.5 * radius * abs(grades[k] - grades[k - 1]), 1.0e-6)
        if points[k] - half < xs[-1]:
            raise GradientError(f"the vertical curve at {points[k]} m (R = {radius:g} m) overlaps the one "
                                f"before it or the change point at {points[k - 1]} m")
        xs += [points[k] - half, points[k] + half]
        ys += [grades[k - 1], grades[k]]
    return GradientProfile(np.array(xs), np.array(ys))
