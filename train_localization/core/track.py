"""Track description: chainage, 2-D alignment and wayside equipment (config/*.yaml).

Chainage runs from 0 to ``length`` [m] in the track's reference direction
(README.md). A ``closed: true`` track is a loop (the rotating disc of seed 003):
chainage ``length`` is chainage 0 again; ``wrap`` and ``difference`` take positions that run
on past the end (an unwrapped distance, as the fusion integrates it) back onto the loop. The alignment is a chain of segments of constant curvature
(straight: 0, arc: 1/R [1/m], sign = to the left) starting at ``origin``; it is used
only to place the train in ``map`` for visualisation and odometry messages.

Equipment is listed per kind. Each entry is a dict with at least ``id`` and
``position`` [m]; a generator entry ``{every: d, start: s0, end: s1, id: "BG{n:03d}"}``
expands to one item every ``d`` metres (its other string values may use ``{n}`` too, e.g. a
balise's ``group: "BG{n:03d}"``). Extra keys (a balise telegram, an LRL code,
a base station's lateral offset, ...) stay in the dict for the sensor models.

Equipment that can fail together (base stations on one timing node, balises of one survey) is
the ``common_cause`` block: core/common_cause.py.

The track's rise along its chainage is the ``gradient`` block (core/gradient.py); a track
without one is level. Its place on the Earth (WGS-84), for GNSS fixes, is the ``geodetic``
block (core/geodesy.py).

ETCS data (balise groups' Q_LOCACC, linking) are the ``etcs`` block and keys of the
``eurobalise`` items: core/etcs/track_data.py.

Equipment that extends along the track (INPO sections ``inpo_section``, pattern belts
``pattern_belt``, LZB cable loops ``lzb_loop``, track circuits ``track_circuit``) gives its start as ``position`` (or
``start``) and its extent as ``end`` or ``length`` [m]; the sensor module checks the rest
(e.g. core/sensors/lzb.py ``loop_table``: loop ``number``, crossing ``spacing``, feeder
cases ``feeders``; at most 12.7 km, fed within 300 m)::

    lzb_loop:
      - {id: L01, number: 1, start: 0.0, end: 600.0}
      - {id: L02, number: 2, position: 600.0, length: 1200.0, spacing: 100.0, feeders: [900.0, 1500.0]}
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from . import common_cause, gradient
from .common_cause import CommonCause
from .geodesy import GeodesyError, GeodeticAnchor
from .gradient import GradientProfile


class TrackError(ValueError):
    """A track file that cannot be used, with the reason."""


def _common_cause(data: dict, equipment: dict[str, list[dict]]) -> tuple[CommonCause, ...]:
    """The track's ``common_cause`` groups (core/common_cause.py), refused as a TrackError."""
    try:
        return common_cause.parse(data.get("common_cause"), equipment)
    except common_cause.CommonCauseError as exc:
        raise TrackError(f"track '{data.get('track_id')}': {exc}") from None


def _gradient(data: dict) -> GradientProfile | None:
    """The track's ``gradient`` profile (core/gradient.py), refused as a TrackError."""
    try:
        return gradient.parse(data.get("gradient"), float(data["length"]))
    except gradient.GradientError as exc:
        raise TrackError(f"track '{data.get('track_id')}': {exc}") from None


def _expand(kind: str, entries: list) -> list[dict]:
    items: list[dict] = []
    for entry in entries or []:
        if not isinstance(entry, dict):
            raise TrackError(f"equipment '{kind}': entry {entry!r} is not a mapping")
        if "every" in entry:
            every, start, end = float(entry["every"]), float(entry.get("start", 0.0)), float(entry["end"])
            if every <= 0:
                raise TrackError(f"equipment '{kind}': 'every' must be > 0")
            template = str(entry.get("id", kind + "{n:03d}"))
            extra = {k: v for k, v in entry.items() if k not in ("every", "start", "end", "id")}
            for n, pos in enumerate(np.arange(start, end + 1e-9, every)):
                items.append({**{k: v.format(n=n) if isinstance(v, str) else v for k, v in extra.items()},
                              "id": template.format(n=n), "position": float(pos)})
        else:
            if "position" not in entry and "start" not in entry:
                raise TrackError(f"equipment '{kind}': entry {entry!r} has no 'position'")
            # an extended item (a loop, a belt) may name its start 'start'
            items.append({**entry, "id": str(entry.get("id", f"{kind}{len(items):03d}")),
                          "position": float(entry.get("position", entry.get("start")))})
    items.sort(key=lambda item: item["position"])
    return items


def extent(kind: str, item: dict, default_end: float | None = None) -> tuple[float, float]:
    """(start, end) [m] of an item that extends along the track: its ``position`` (or ``start``)
    and its ``end`` or ``length``; ``default_end`` if it gives neither (TrackError if None)."""
    start = float(item.get("start", item["position"]))
    if "end" in item:
        end = float(item["end"])
    elif "length" in item:
        end = start + float(item["length"])
    elif default_end is not None:
        end = float(default_end)
    else:
        raise TrackError(f"{kind} '{item['id']}' has neither 'end' nor 'length'")
    return start, end


def nearest(positions: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Index of the nearest of sorted ``positions`` to each ``x``, and x minus it [m]."""
    k = np.searchsorted(positions, x)
    lo = np.clip(k - 1, 0, positions.size - 1)
    hi = np.clip(k, 0, positions.size - 1)
    idx = np.where(np.abs(x - positions[lo]) <= np.abs(x - positions[hi]), lo, hi)
    return idx, x - positions[idx]


def nearby_runs(positions: np.ndarray, x: np.ndarray, radius: float):
    """Split samples ``x`` into runs near the same item of sorted ``positions``.

    Returns (offsets x - nearest position [m], [(first, end, item index or -1), ...]):
    consecutive samples within ``radius`` of the same item form one run, the others
    runs with index -1.
    """
    idx, u = nearest(positions, x)
    key = np.where(np.abs(u) < radius, idx, -1)
    starts = np.r_[0, np.flatnonzero(np.diff(key)) + 1]
    ends = np.r_[starts[1:], x.size]
    return u, [(int(a), int(b), int(key[a])) for a, b in zip(starts, ends)]


@dataclass
class Track:
    """A named track: length [m], alignment polyline and equipment by kind."""

    track_id: str
    length: float
    equipment: dict[str, list[dict]] = field(default_factory=dict)
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)
    segments: list[tuple[float, float]] = field(default_factory=list)  # (length [m], curvature [1/m])
    resolution: float = 10.0  # polyline step [m]
    closed: bool = False      # a loop: chainage ``length`` is chainage 0 again (the rig's disc, seed 003)
    etcs: dict = field(default_factory=dict)  # ETCS data: national values, linking (core/etcs/track_data.py)
    common_cause: tuple[CommonCause, ...] = ()  # equipment that can fail together (core/common_cause.py)
    gradient: GradientProfile | None = None     # rise along the chainage (core/gradient.py); None: level
    geodetic: GeodeticAnchor | None = None      # WGS-84 place of the map frame (core/geodesy.py); None: none

    def __post_init__(self):
        if not (self.length > 0 and math.isfinite(self.length)):
            raise TrackError(f"track '{self.track_id}': length must be a positive number")
        for kind, items in self.equipment.items():
            for item in items:
                if not 0.0 <= item["position"] <= self.length:
                    raise TrackError(f"{kind} '{item['id']}' at {item['position']} m is off the track "
                                     f"(0..{self.length} m)")
        if self.etcs:   # refused on load, in one line, like the rest of the file
            from .etcs.track_data import EtcsData
            EtcsData.from_track(self)
        self._build_polyline()

    def _build_polyline(self):
        segments = list(self.segments) or [(self.length, 0.0)]
        covered = sum(seg[0] for seg in segments)
        if covered < self.length:  # the rest of the track is straight
            segments.append((self.length - covered, 0.0))
        s_pts, x_pts, y_pts, h_pts = [0.0], [self.origin[0]], [self.origin[1]], [self.origin[2]]
        s = 0.0
        for seg_len, curvature in segments:
            n = max(1, int(math.ceil(seg_len / self.resolution)))
            ds = seg_len / n
            for _ in range(n):
                h0 = h_pts[-1]
                h1 = h0 + curvature * ds
                hm = 0.5 * (h0 + h1)
                x_pts.append(x_pts[-1] + ds * math.cos(hm))
                y_pts.append(y_pts[-1] + ds * math.sin(hm))
                h_pts.append(h1)
                s += ds
                s_pts.append(s)
        self._s = np.array(s_pts)
        self._x = np.array(x_pts)
        self._y = np.array(y_pts)
        self._h = np.array(h_pts)

    @property
    def circumference(self) -> float | None:
        """[m] of a closed track (what scores compare positions modulo), None on an open one."""
        return self.length if self.closed else None

    def wrap(self, chainage):
        """Chainage [m] (number or array) on a closed track taken into [0, length); unchanged on an
        open one. Positions that run on past the end of a loop (an unwrapped distance) are
        compared and looked up through it."""
        return np.mod(chainage, self.length) if self.closed else chainage

    def difference(self, a, b):
        """a - b [m]; on a closed track the shortest way round, in [-length/2, length/2)."""
        d = np.asarray(a, dtype=float) - np.asarray(b, dtype=float)
        if self.closed:
            d = np.mod(d + 0.5 * self.length, self.length) - 0.5 * self.length
        return d if d.ndim else float(d)

    def pose(self, chainage: float) -> tuple[float, float, float]:
        """(x [m], y [m], heading [rad]) of a chainage in ``map`` (clamped to the polyline)."""
        chainage = self.wrap(chainage)
        return (float(np.interp(chainage, self._s, self._x)),
                float(np.interp(chainage, self._s, self._y)),
                float(np.interp(chainage, self._s, self._h)))

    def curvature(self, chainage):
        """Curvature [1/m] (+ to the left of increasing chainage) of the alignment at chainages
        (number or array): its segment's, 0 beyond the segments and off the track's ends."""
        table = getattr(self, "_curvature_table", None)
        if table is None:
            ends = np.cumsum([seg[0] for seg in self.segments]) if self.segments else np.zeros(0)
            table = self._curvature_table = (ends, np.array([seg[1] for seg in self.segments] + [0.0]))
        ends, kappa = table
        c = np.asarray(self.wrap(np.asarray(chainage, dtype=float)))
        out = kappa[np.searchsorted(ends, c, side="right")]
        out = np.where((c < 0.0) | (c > self.length), 0.0, out)
        return out if out.ndim else float(out)

    def grade(self, chainage):
        """Gradient [1, rise / run] (+ rising towards increasing chainage) at chainages [m] (number or
        array): the ``gradient`` profile's, 0 on a level track."""
        c = self.wrap(np.asarray(chainage, dtype=float))
        if self.gradient is None:
            out = np.zeros(np.shape(c))
            return out if out.ndim else 0.0
        return self.gradient.at(c)

    def xy(self, chainage) -> tuple[np.ndarray, np.ndarray]:
        """Map coordinates (x [m], y [m]) of chainages (array), on the polyline ``pose`` uses."""
        s = self.wrap(np.asarray(chainage, dtype=float))
        return np.interp(s, self._s, self._x), np.interp(s, self._s, self._y)

    PROJECT_CHUNK = 256   # polyline segments compared at once: bounds project()'s memory per point

    def segments_table(self) -> tuple[np.ndarray, ...]:
        """(x0, y0, dx, dy, squared length, chainage at start, length) of the polyline's segments,
        computed once (project() uses them; a decoder builds them when it is made)."""
        table = getattr(self, "_segments_table", None)
        if table is None:
            dx, dy = np.diff(self._x), np.diff(self._y)
            table = (self._x[:-1], self._y[:-1], dx, dy, np.maximum(dx * dx + dy * dy, 1e-18), self._s[:-1],
                     np.diff(self._s))
            self._segments_table = table
        return table

    def project(self, x, y) -> tuple[np.ndarray, np.ndarray]:
        """Map points (x, y) [m] onto the alignment: (chainage [m], signed lateral offset [m],
        + to the left of the reference direction) of the nearest point of the polyline that
        ``pose`` and ``xy`` interpolate, so that project(xy(s)) = (s, 0). A point beyond an end
        of the track projects onto that end (chainage 0 or ``length``), its lateral offset then
        being its distance from it, signed by its side. Where two parts of the alignment are
        equally near (a track that comes back near itself) the lower chainage wins. The segments
        are compared PROJECT_CHUNK at a time (memory independent of the track's length)."""
        px = np.atleast_1d(np.asarray(x, dtype=float))
        py = np.atleast_1d(np.asarray(y, dtype=float))
        x0, y0, dx, dy, _, s0, ds = self.segments_table()
        chain = np.empty(px.size)
        lateral = np.empty(px.size)
        for i in range(px.size):
            best = (math.inf, 0, 0.0)
            for a, f, d2 in self._nearest_on_segments(px[i], py[i]):
                k = int(np.argmin(d2))
                if d2[k] < best[0]:
                    best = (float(d2[k]), a + k, float(f[k]))
            _, k, f = best
            chain[i] = s0[k] + f * ds[k]
            rx, ry = px[i] - x0[k], py[i] - y0[k]
            side = dx[k] * ry - dy[k] * rx      # cross product: > 0 to the left
            dist = math.hypot(rx - f * dx[k], ry - f * dy[k])
            lateral[i] = math.copysign(dist, side) if side != 0.0 else 0.0
        return chain, lateral

    def distance_elsewhere(self, x: float, y: float, chainage: float, margin: float) -> float:
        """Distance [m] from the map point (x, y) to the alignment away from ``chainage``: its
        nearest point more than ``margin`` [m] along the track from there (inf if there is none).
        Small where the track crosses or comes back near itself (a flyover, a hairpin), where a
        point near the alignment cannot tell which part it is near."""
        _, _, _, _, _, s0, ds = self.segments_table()
        best = math.inf
        for a, f, d2 in self._nearest_on_segments(x, y):
            b = a + f.size
            away = np.abs(self.difference(s0[a:b] + f * ds[a:b], chainage)) > margin
            if away.any():
                best = min(best, float(d2[away].min()))
        return math.sqrt(best)

    def _nearest_on_segments(self, x: float, y: float):
        """For each PROJECT_CHUNK segments of the polyline from segment a: (a, f, d2), f [1] the
        fraction along each segment of its point nearest to (x, y) [m], d2 [m^2] its squared
        distance (memory independent of the track's length)."""
        x0, y0, dx, dy, seg2, _, _ = self.segments_table()
        for a in range(0, dx.size, self.PROJECT_CHUNK):
            b = a + self.PROJECT_CHUNK
            rx, ry = x - x0[a:b], y - y0[a:b]
            f = np.clip((rx * dx[a:b] + ry * dy[a:b]) / seg2[a:b], 0.0, 1.0)
            yield a, f, np.square(rx - f * dx[a:b]) + np.square(ry - f * dy[a:b])

    def items(self, kind: str) -> list[dict]:
        """Equipment of one kind, sorted by position (empty if the track has none)."""
        return self.equipment.get(kind, [])

    def item(self, kind: str, item_id: str) -> dict:
        """One piece of equipment by id; KeyError if unknown."""
        for it in self.items(kind):
            if it["id"] == item_id:
                return it
        raise KeyError(f"unknown {kind} id {item_id!r} on track {self.track_id}")

    @classmethod
    def from_dict(cls, data: dict) -> "Track":
        try:
            origin = data.get("origin", {}) or {}
            equipment = {kind: _expand(kind, entries) for kind, entries in (data.get("equipment", {}) or {}).items()}
            return cls(
                track_id=str(data["track_id"]),
                length=float(data["length"]),
                origin=(float(origin.get("x", 0.0)), float(origin.get("y", 0.0)),
                        float(origin.get("heading", 0.0))),
                segments=[(float(s["length"]), float(s.get("curvature", 0.0)))
                          for s in data.get("alignment", []) or []],
                equipment=equipment,
                closed=bool(data.get("closed", False)),
                resolution=float(data.get("resolution", 10.0)),
                etcs=data.get("etcs") or {},
                common_cause=_common_cause(data, equipment),
                gradient=_gradient(data),
                geodetic=GeodeticAnchor.from_dict(data.get("geodetic")),
            )
        except KeyError as exc:
            raise TrackError(f"track description lacks the key {exc}") from None
        except GeodesyError as exc:
            raise TrackError(f"track {data.get('track_id')!r}: {exc}") from None

    @classmethod
    def from_yaml(cls, path: str | Path) -> "Track":
        with open(path, encoding="utf-8") as fh:
            return cls.from_dict(yaml.safe_load(fh))
