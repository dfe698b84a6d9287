"""A surveyed polyline as the network's alignment: constant-curvature segments (core/track.py).

OSM ways and railML geometry give a track as points; a section's alignment is a chain of
arcs (curvature constant on each, straights at 0). Between two points the track is drawn as
a biarc: two arcs that leave the first point along its tangent, meet, and arrive at the
second along its tangent (the equal-length construction of Bolton 1975), so that every
point is passed exactly (the chainage of a point is the length of the arcs before it, and a
section ends where its last point is) and the heading is continuous. The tangent at an
inner point bisects the chords on its two sides; at a section's end it is the one the
caller gives (a switch's through route: the same on every leg it joins), or the one that
lets a single arc reach the next point's tangent.
"""
from __future__ import annotations

import math
from dataclasses import dataclass


def wrap(a: float) -> float:
    """a in (-pi, pi]."""
    return math.atan2(math.sin(a), math.cos(a))


@dataclass(frozen=True)
class Fitted:
    """The alignment of a polyline: its segments (length [m], curvature [1/m]), the chainage
    [m] of every point, and the heading [rad] at the first point."""

    segments: list[tuple[float, float]]
    chainages: list[float]
    heading: float

    @property
    def length(self) -> float:
        return self.chainages[-1]


def chord_heading(p, q) -> float:
    return math.atan2(q[1] - p[1], q[0] - p[0])


def inner_headings(points) -> list[float | None]:
    """The tangent at every inner point (the bisector of its chords); None at the two ends."""
    out: list[float | None] = [None] * len(points)
    for k in range(1, len(points) - 1):
        a, b = chord_heading(points[k - 1], points[k]), chord_heading(points[k], points[k + 1])
        out[k] = a + 0.5 * wrap(b - a)
    return out


def _arc(p, heading: float, q) -> tuple[float, float, float]:
    """(length, curvature, end heading) of the arc from ``p`` leaving along ``heading`` to ``q``."""
    chord = math.hypot(q[0] - p[0], q[1] - p[1])
    if chord < 1e-9:
        return 0.0, 0.0, heading
    turn = 2.0 * wrap(chord_heading(p, q) - heading)
    if abs(turn) < 1e-12:
        return chord, 0.0, heading
    length = chord * (0.5 * turn) / math.sin(0.5 * turn)
    return length, turn / length, heading + turn


def _biarc(p0, h0: float, p1, h1: float) -> list[tuple[float, float]]:
    """The two arcs from p0 (tangent h0) to p1 (tangent h1)."""
    t0, t1 = (math.cos(h0), math.sin(h0)), (math.cos(h1), math.sin(h1))
    v = (p1[0] - p0[0], p1[1] - p0[1])
    vv = v[0] ** 2 + v[1] ** 2
    vt = v[0] * (t0[0] + t1[0]) + v[1] * (t0[1] + t1[1])
    a = 2.0 * (t0[0] * t1[0] + t0[1] * t1[1] - 1.0)   # <= 0
    root = vt + math.sqrt(max(vt * vt - a * vv, 0.0))
    # the positive root of a d^2 - 2 vt d + vv = 0, in the form that holds as a -> 0 (parallel tangents)
    d = vv / root if root > 1e-12 else 0.5 * math.sqrt(vv)
    joint = (0.5 * (p0[0] + d * t0[0] + p1[0] - d * t1[0]), 0.5 * (p0[1] + d * t0[1] + p1[1] - d * t1[1]))
    l1, k1, hm = _arc(p0, h0, joint)
    l2, k2, _ = _arc(joint, hm, p1)
    return [(length, k) for length, k in ((l1, k1), (l2, k2)) if length > 0.0]


def fit(points, begin_heading: float | None = None, end_heading: float | None = None) -> Fitted:
    """The alignment through ``points`` (map x, y [m]; two or more, distinct) with the given
    tangents at its ends (None: the natural one, module docstring)."""
    if len(points) < 2:
        raise ValueError("a polyline needs two points or more")
    heads = inner_headings(points)
    if begin_heading is None:   # the tangent from which one arc reaches the next point's tangent
        nxt = heads[1] if len(points) > 2 else (end_heading if end_heading is not None else
                                                 chord_heading(points[0], points[1]))
        begin_heading = 2.0 * chord_heading(points[0], points[1]) - nxt
    heads[0] = begin_heading
    if end_heading is None:
        prev = heads[-2]
        end_heading = 2.0 * chord_heading(points[-2], points[-1]) - prev
    heads[-1] = end_heading
    segments, chainages = [], [0.0]
    for k in range(len(points) - 1):
        h0 = heads[k]
        h1 = h0 + wrap(heads[k + 1] - h0)
        arcs = _biarc(points[k], h0, points[k + 1], h1)
        segments += arcs
        chainages.append(chainages[-1] + sum(length for length, _ in arcs))
    return Fitted(segments, chainages, wrap(begin_heading))


def scaled(fitted: Fitted, length: float) -> Fitted:
    """The alignment stretched to ``length`` (a length the source states, railML's): every
    segment and chainage by the same factor, each segment's turn kept."""
    k = length / fitted.length
    return Fitted([(seg_len * k, curvature / k) for seg_len, curvature in fitted.segments],
                  [c * k for c in fitted.chainages], fitted.heading)
