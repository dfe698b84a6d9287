"""Axle counter (wayside train detection), seed 004.

Physics (seed 004 section 2.2): an axle counter head is an electromagnetic
(inductive) wheel detector on the rail; the evaluation unit counts the axles that
enter and leave the section between two heads, and the difference count in - count
out gives the occupancy of the section. Seed 004 section 4.2 places three counting
points around a neutral section (two sections, both directions of running). The
direction of an axle comes from the two sensor systems of a double wheel sensor.

Wheel sensor model: each head is a double wheel sensor with two inductive systems
Sa and Sb ``sensor_spacing`` apart along the rail (Sa at position - spacing/2, Sb at
position + spacing/2), like the double sensors of axle counters (e.g. Frauscher
RSR180 type). A wheel flange entering a system's field damps its oscillator; the
evaluation board reports the damping normalised to 0 (no wheel) .. ~1 (nominal
flange centred over the system). Damping versus the along-track distance u of the
wheel from the system centre: a bell exp(-u^2 / (2 w^2)), w = ``zone_width`` =
0.085 m (about 0.2 m FWHM: the chord over which the flange of a 0.92 m wheel,
28 mm flange height of the S1002 profile, dips below the sensor top), times the
wheel's amplitude (flange height/wear, ``damping_spread``) and the system's gain.
Noise: white electronics/EMI noise, a slow drift of the idle level (temperature),
and short single-system EMI spikes (traction current, rail brakes) that the
two-system sequence check must reject.

Vehicle: ``Scenario.vehicle.axles`` are the axle offsets behind the front [m]. With
orientation o (+1: the front faces increasing chainage), axle k is at
chainage front - o * axles[k]. ``orientation`` 0 (default) = auto: the simulator
takes the sign of the first motion (a train starts front first; reversals back
up), the decoder the direction of the first passage identified as a train's (a
spurious axle counted before it, EMI or a trolley, does not set it: it would put
every front fix off by the train's length).

Track equipment (kind ``axle_counter_head``)::

    axle_counter_head:
      - {id: AC01, position: 1000.0}
      - {id: AC02, position: 1800.0, section: NS1}   # optional name of the section beyond (+ side)
      - {every: 800.0, start: 1000.0, end: 2600.0, id: "AC{n:02d}"}

Sections lie between consecutive heads (by chainage). Section k (between heads k and
k+1) is called ``<id_k>-<id_k+1>`` unless head k has a ``section`` key. The areas
before the first and after the last head are not monitored. Parameter ``heads``
restricts a device (one evaluation unit) to a subset of the heads.

Raw signal: per head two channels ``<head id>.a`` and ``<head id>.b`` [1]
(normalised damping) at ``sample_rate`` (default 2 kHz). At 300 km/h (83 m/s) a
wheel stays 2.4 ms (5 samples) above the threshold and Sb lags Sa by 1.7 ms (3.4
samples, 0.14 m); at 500 km/h still 1.4 ms / 1 ms. Rate = 2 x heads x 2 kHz: 4000
samples/s per head, so the default suits up to 5 heads (20k samples/s, e.g. the
three counting points of seed 004 section 4.2); a longer line uses several units
(``heads``). The channel layout depends on the track, so the decoder checks it
itself (``AxleCounterDecoder.channels`` is empty).

Faults for tests (``faults``, ';'-separated): ``HEAD@T:missed`` suppresses the
first wheel that enters the head's field after time T (flange not detected);
``HEAD@T:extra`` (``extra-``: decreasing direction) adds a wheel-like damping
sequence through the head at 5 m/s centred at T (a spurious axle).

Decoder:
  * per system, hysteresis (on at ``threshold_on``, off below ``threshold_off``);
  * per head, an episode runs from the first system damped until both are free.
    It is an axle if both systems were damped and the order of the damping starts
    equals the order of the ends: Sa first -> increasing direction, Sb first ->
    decreasing; other sequences (a wheel rocking back, a spike on one system, a
    lag faster than ``max_speed``) are not counted. The axle passed the head centre
    at the mean of the four on-level crossing times (interpolated), its speed is
    sensor_spacing / lag;
  * counting: an axle at head k moving + leaves region k and enters region k+1
    (region 0 / H = the unmonitored outer areas); each section keeps axles_in,
    axles_out and count = in - out (``Areas``: the regions on either side of each head; on a
    network they run across the nodes, core/network/wayside.py);
  * state per section: CLEAR (count 0), OCCUPIED (count > 0), DISTURBED, which is
    latched until ``reset_section(section_id)``. A section becomes DISTURBED when
      (A) its count goes negative (more axles out than in), or
      (B) a neighbour section to which it passed axles counts the train out: when a
          section j reaches count 0 by an axle leaving it, every adjacent section q
          with count > 0 whose latest axle event was an axle leaving q into j has
          a residual count although its train has left -> DISTURBED.
    Rule B assumes one train per section (block working) and sections longer than
    the largest axle gap of a train (~18 m bogie distance; block and neutral
    sections are hundreds of metres, seed 004 section 4.2). A spurious extra
    axle in the last monitored section cannot be detected (nothing beyond counts
    the train out); it stays OCCUPIED, the safe side. The counters start CLEAR
    (after a reset), or DISTURBED with ``start_disturbed``;
  * outputs: SectionOccupancy of all sections whenever a section changes state
    (stamp = time the axle was counted), after a reset, at the first block and
    every ``report_period`` s; a PositionFix of the train front whenever an axle
    passes a head into an empty, undisturbed region (the first axle of a train):
    front = head + o * ``first_axle_offset`` when the front leads (direction = o),
    or head + o * ``last_axle_offset`` when the train backs (skipped if that
    parameter is 0). Its stddev combines the head survey, the axle offset and the
    timing (speed x 0.25 sample), plus 0.1 m if the axle stopped over the head;
  * first-axle identification (see _Passage): when the first counted axle was not
    the train's first (the real first axle missed, or a spurious axle before it),
    the front fix would be one axle spacing off. The decoder cannot tell at the first
    detection, so it holds the fix and follows the passage: the distances between the
    next axles at that head (time between detections x their mean speed) are matched
    against the spacings of ``axle_offsets`` under three hypotheses: nothing wrong,
    first axle missed, one spurious axle before the first (consecutive axles must
    also move at speeds one train can have). It publishes (stamped at the passage of
    the identified axle) as soon as exactly one hypothesis has matched a spacing of
    the layout and no other fits (normally at the second axle); after ``identify_time`` it publishes the most
    likely fitting one with its stddev inflated so that the fronts of all fitting
    hypotheses lie within 3.3 sigma, or withholds the fix (``stats``:
    front_identified_shifted, front_inflated, front_unidentified).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..measurements import CLEAR, DISTURBED, OCCUPIED, PositionFix, SectionOccupancy, SectionState
from ..signals import InputRejected, RawBlock
from ..track import Track, TrackError
from .base import MIN_FIX_SIGMA, Decoder, ErrorModel, Param, ReferenceTable, ReferenceWindow, SensorSpec, Simulator

HEAD_KIND = "axle_counter_head"

PARAMS = {
    "sensor_spacing": Param(0.14, "distance of the two sensor systems Sa, Sb of a head along the rail [m] "
                                  "(double wheel sensor)", (0.01, 1.0)),
    "zone_width": Param(0.085, "1-sigma half-width of a system's damping zone [m] (~0.2 m FWHM, flange "
                               "chord of a 0.92 m wheel, S1002 profile)", (5.0e-3, 0.5)),
    "damping_spread": Param(0.10, "1-sigma spread of the damping amplitude between wheels (flange height "
                                  "and wear) [fraction]", (0.0, 1.0)),
    "gain_spread": Param(0.05, "1-sigma spread of the gain between sensor systems [fraction]", (0.0, 1.0)),
    "noise_sigma": Param(0.02, "1-sigma white noise of the normalised damping [1] (electronics, EMI)", (0.0, 1.0)),
    "drift_sigma": Param(0.02, "1-sigma slow drift of the idle level [1] (temperature)", (0.0, 1.0)),
    "drift_tau": Param(60.0, "correlation time of the idle-level drift [s]", (1.0e-3, 1.0e6)),
    "spike_rate": Param(0.01, "EMI spikes per sensor system per second [1/s] (traction current, rail brakes)",
                        (0.0, 100.0)),
    "spike_amplitude": Param(0.8, "peak normalised damping of an EMI spike [1]", (0.0, 2.0)),
    "threshold_on": Param(0.5, "damping above which a system is occupied by a wheel [1]", (0.0, 1.0)),
    "threshold_off": Param(0.3, "damping below which a system is free again (hysteresis) [1]", (0.0, 1.0)),
    "max_speed": Param(200.0, "sequences faster than this (sensor_spacing / lag) are not axles [m/s]; "
                              "500 km/h = 139 m/s plus the lag error of a 2 kHz sampled pulse (~10 %)",
                       (1.0, 500.0)),
    "heads": Param("", "comma-separated head ids of this evaluation unit; empty = all heads of the track"),
    "orientation": Param(0, "+1: train front faces increasing chainage, -1: decreasing, 0: auto (first motion "
                            "/ the first passage identified as a train's) [1]", (-1, 1)),
    "front_first": Param(False, "every train passes front first (a wayside unit on a line with trains of both "
                                "directions): each passage's direction is its train's orientation, and "
                                "``orientation`` is not used by the decoder; a backing train's fix would be off by "
                                "its length (left to the association with the trains' fused intervals)"),
    "first_axle_offset": Param(2.5, "distance of the first axle behind the train front [m] (vehicle data); "
                                    "within a train of up to 1 km", (0.0, 1000.0)),
    "last_axle_offset": Param(0.0, "distance of the last axle behind the front [m]; 0 = unknown: no front "
                                   "fix while the train backs", (0.0, 1000.0)),
    "axle_offsets": Param([], "axle layout: offsets of all axles behind the front [m] (vehicle data; the "
                              "vehicle's axles unless set). The spacings of the first axles of a passage "
                              "identify its first axle (a missed or spurious one) before the front fix is "
                              "published; empty = no layout: the fix's stddev covers the measured first "
                              "spacing instead"),
    "identify_time": Param(1.5, "longest wait after the first axle of a passage for the axles that identify "
                                "it [s]; then the fix covers the hypotheses left or is withheld (the fusion "
                                "takes measurements up to 2 s late)", (0.0, 60.0)),
    "axle_offset_sigma": Param(0.02, "1-sigma of the configured axle offsets [m]", (0.0, 1.0)),
    "head_position_sigma": Param(0.02, "1-sigma error of the surveyed head chainage in the track file [m] "
                                       "(simulated: real heads are displaced by it)", (0.0, 1.0)),
    "report_period": Param(1.0, "period of the SectionOccupancy report without state changes [s]",
                           (1.0e-3, 3600.0)),
    "start_disturbed": Param(False, "sections start DISTURBED (as after power-up) instead of CLEAR"),
    "faults": Param("", "injected miscounts 'HEAD@T:missed', 'HEAD@T:extra', 'HEAD@T:extra-' separated by "
                        "';' (tests)"),
}


def device_heads(track: Track, params: dict) -> list[dict]:
    items = track.items(HEAD_KIND)
    wanted = [h.strip() for h in str(params.get("heads", "")).split(",") if h.strip()]
    if wanted:
        known = {it["id"] for it in items}
        missing = [h for h in wanted if h not in known]
        if missing:
            raise TrackError(f"{HEAD_KIND} {', '.join(missing)} not on track {track.track_id}")
        items = [it for it in items if it["id"] in wanted]
    if not items:
        raise TrackError(f"no {HEAD_KIND} on track {track.track_id}: an axle counter needs heads")
    if len({it["id"] for it in items}) != len(items):
        raise TrackError(f"{HEAD_KIND} ids are not unique")
    return items


def channel_layout(heads: list[dict]) -> tuple[tuple[str, ...], tuple[str, ...]]:
    names = tuple(f"{h['id']}.{s}" for h in heads for s in ("a", "b"))
    return names, ("1",) * len(names)


def section_ids(heads: list[dict]) -> list[str]:
    return [str(heads[k].get("section", f"{heads[k]['id']}-{heads[k + 1]['id']}")) for k in range(len(heads) - 1)]


@dataclass(frozen=True)
class Areas:
    """The areas the heads bound, which the counter counts axles in and out of (seed 004
    section 2.2). Area ``left[h]`` lies on the decreasing-chainage side of head h (along its
    own track), ``right[h]`` on the other; ``sections``: (area, section id, start, end [m]) of
    every monitored area, in report order (start, end: its bounding heads' chainages; NaN for an
    area over several tracks); every other area is unmonitored (beyond the outermost heads)."""

    left: tuple[int, ...]
    right: tuple[int, ...]
    sections: tuple[tuple[int, str, float, float], ...]
    count: int

    @classmethod
    def line(cls, heads: list[dict]) -> "Areas":
        """Along one track: area k between heads k - 1 and k, areas 0 and H unmonitored."""
        nh = len(heads)
        return cls(tuple(range(nh)), tuple(range(1, nh + 1)),
                   tuple((k + 1, sid, float(heads[k]["position"]), float(heads[k + 1]["position"]))
                         for k, sid in enumerate(section_ids(heads))), nh + 1)

    def monitored(self) -> frozenset[int]:
        return frozenset(a for a, *_ in self.sections)

    def across(self) -> list[list[tuple[int, int]]]:
        """Per area: (head, the area on its other side) of every head bounding it."""
        out: list[list[tuple[int, int]]] = [[] for _ in range(self.count)]
        for h, (a, b) in enumerate(zip(self.left, self.right)):
            out[a].append((h, b))
            out[b].append((h, a))
        return out


def _parse_faults(text: str, head_ids: list[str]) -> list[tuple[int, float, str]]:
    faults = []
    for item in filter(None, (s.strip() for s in str(text).split(";"))):
        try:
            head, rest = item.split("@")
            t, kind = rest.split(":")
            t, kind, head = float(t), kind.strip(), head.strip()
        except ValueError:
            raise ValueError(f"malformed axle counter fault {item!r}; expected 'HEAD@T:missed|extra|extra-'") from None
        if kind not in ("missed", "extra", "extra+", "extra-"):
            raise ValueError(f"unknown axle counter fault kind {kind!r}")
        if head not in head_ids:
            raise ValueError(f"axle counter fault names unknown head {head!r}")
        faults.append((head_ids.index(head), t, kind))
    return faults


class AxleCounterSimulator(Simulator):
    sensor = "axle_counter"
    sees_all_trains = True
    channels = ()  # per instance: two per head (the layout depends on the track)
    units = ()
    adc_lsb = {"1": 1 / 1024}  # 10-bit conversion of the normalised damping
    default_sample_rate = 2000.0

    def __init__(self, *args):
        super().__init__(*args)
        p = self.params
        self.heads = device_heads(self.track, p)
        self.channels, self.units = channel_layout(self.heads)
        nh = len(self.heads)
        # the real heads lie where the survey (track file) says, within head_position_sigma
        self.head_pos = np.array([h["position"] for h in self.heads], float) + \
            self.rng.normal(0.0, p["head_position_sigma"], nh)
        self.axles = np.concatenate([np.asarray(v.axles, float) for v in self.fleet])  # every train's
        na = len(self.axles)
        self.amp = np.clip(1.0 + self.rng.normal(0.0, p["damping_spread"], na), 0.6, None)
        self.gain = np.clip(1.0 + self.rng.normal(0.0, p["gain_spread"], (nh, 2)), 0.7, None)
        self.drift = self.rng.normal(0.0, p["drift_sigma"], 2 * nh)
        self.faults = [[hi, t, kind, "armed", -1, None]
                       for hi, t, kind in _parse_faults(p["faults"], [h["id"] for h in self.heads])]
        self._spike_left = np.zeros(2 * nh)
        self._spike_amp = np.zeros(2 * nh)

    def samples(self, times, position, speed, acceleration):
        p = self.params
        n, nh = len(times), len(self.heads)
        dt = 1.0 / self.sample_rate
        w = p["zone_width"]
        half = 0.5 * p["sensor_spacing"]
        out = np.zeros((n, 2 * nh))
        self.orientations(speed)
        wheels = np.concatenate(self.axle_chainages(position), axis=1)  # (n, axles of all trains)
        reach = 6.0 * w + half
        for hi in range(nh):
            if not len(self.axles):
                break
            du = wheels - self.head_pos[hi]
            near = np.abs(du) < reach
            if not near.any() and not any(f[0] == hi and f[2] == "missed" and f[3] != "done"
                                          for f in self.faults):
                continue
            amp = np.broadcast_to(self.amp, du.shape).copy()
            for f in self.faults:
                if f[0] == hi and f[2] == "missed":
                    self._apply_missed(f, times, near, amp)
            for s, sign in ((0, -1.0), (1, 1.0)):
                u = du - sign * half
                out[:, 2 * hi + s] += self.gain[hi, s] * np.sum(amp * np.exp(-0.5 * (u / w) ** 2), axis=1)
        for hi, t, kind, *_ in self.faults:
            if kind.startswith("extra") and times[0] - 0.3 <= t <= times[-1] + 0.3:
                d = -1.0 if kind == "extra-" else 1.0
                u = d * 5.0 * (times - t)
                for s, sign in ((0, -1.0), (1, 1.0)):
                    out[:, 2 * hi + s] += self.gain[hi, s] * np.exp(-0.5 * ((u - sign * half) / w) ** 2)
        # idle-level drift (AR(1), held over a block), white noise, EMI spikes on single systems
        phi = math.exp(-n * dt / p["drift_tau"])
        self.drift = phi * self.drift + math.sqrt(1.0 - phi * phi) * p["drift_sigma"] * \
            self.rng.normal(0.0, 1.0, 2 * nh)
        out += self.drift[None, :] + self.rng.normal(0.0, p["noise_sigma"], (n, 2 * nh))
        starts = self.rng.random((n, 2 * nh)) < p["spike_rate"] * dt
        amps = p["spike_amplitude"] * self.rng.uniform(0.5, 1.0, (n, 2 * nh))
        if starts.any() or self._spike_left.any():
            for i in range(n):
                new = starts[i] & (self._spike_left <= 0)
                self._spike_left[new] = 2
                self._spike_amp[new] = amps[i, new]
                on = self._spike_left > 0
                out[i, on] += self._spike_amp[on] * np.where(self._spike_left[on] == 2, 1.0, 0.5)
                self._spike_left[on] -= 1
        return out

    @staticmethod
    def _apply_missed(f, times, near, amp):
        """Suppress the first wheel entering the head's field after the fault time."""
        _, t, _, state, axle, prev = f
        if state == "done":
            return
        if prev is None:
            prev = np.zeros(near.shape[1], dtype=bool)
        before = np.vstack([prev[None, :], near[:-1]])
        if state == "armed":
            entering = near & ~before & (times >= t)[:, None]
            hits = np.argwhere(entering)
            if len(hits):
                i0, axle = hits[0]
                f[3], f[4] = "active", int(axle)
                state = "active"
                leave = np.flatnonzero(~near[i0:, axle])
                i1 = i0 + leave[0] if len(leave) else len(times)
                amp[i0:i1, axle] = 0.0
                if len(leave):
                    f[3] = "done"
        elif state == "active":
            leave = np.flatnonzero(~near[:, axle])
            i1 = leave[0] if len(leave) else len(times)
            amp[:i1, axle] = 0.0
            if len(leave):
                f[3] = "done"
        f[5] = near[-1].copy()


class _Episode:
    """One damping episode of a head: from the first system damped until both are free."""

    __slots__ = ("on", "rise", "fall")

    def __init__(self):
        self.on = [False, False]
        self.rise: list[float | None] = [None, None]
        self.fall: list[float | None] = [None, None]


# identification of the first axle of a passage (see _Passage)
HYPOTHESES = ((0, 0), (0, 1), (1, 0))  # (spurious detections before the first axle, first axle's layout index)
COVER = 3.3      # a fix covers its alternatives within COVER sigma (99.9 %, two-sided)
GAP_REL, GAP_ABS = 0.10, 0.25   # tolerance of a measured axle spacing: fraction of the spacing + [m]
SPEED_REL, ACCEL_MAX = 0.10, 1.5   # speeds of consecutive axles agree within 10 % + 1.5 m/s^2 x time between
OVERDUE_REL, OVERDUE_ABS = 1.5, 0.2   # an axle expected after g / v has not come after 1.5 g / v + 0.2 s


class _Passage:
    """Axles counted at one head in one direction from an axle into an empty region.

    A measured spacing between detections i and i+1 is (v_i + v_i+1) / 2 x (t_i+1 - t_i)
    (trapezoid: exact for constant acceleration); the speeds from the sensor lag are good
    to a few % (interpolated on-level crossings, the mean of rise and fall cancels the
    gain difference of the two systems), hence the tolerance GAP_REL x spacing + GAP_ABS
    (the interpolation at low speed, the head position within the 0.14 m pair).
    """

    __slots__ = ("head", "d", "o", "times", "speeds")

    def __init__(self, head: int, d: int, o: int):
        self.head, self.d, self.o = head, d, o   # o: the train's orientation assumed
        self.times: list[float] = []
        self.speeds: list[float] = []

    def spacing(self, i: int) -> float:
        return 0.5 * (self.speeds[i] + self.speeds[i + 1]) * (self.times[i + 1] - self.times[i])

    def same_train(self, i: int) -> bool:
        """Whether detections i and i+1 move at speeds one train can have."""
        v0, v1 = self.speeds[i], self.speeds[i + 1]
        return abs(v1 - v0) <= SPEED_REL * max(v0, v1) + ACCEL_MAX * (self.times[i + 1] - self.times[i])

    def advance(self) -> float:
        """How far the train moved from the first detection to the second if the first was a
        spurious axle (not the train's: its speed is not the train's)."""
        return self.speeds[1] * (self.times[1] - self.times[0])


class AxleCounterDecoder(Decoder):
    sensor = "axle_counter"
    channels = ()  # layout depends on the track: checked in decode()

    def __init__(self, params: dict, track: Track):
        super().__init__(params, track)
        p = params
        if p["threshold_off"] >= p["threshold_on"]:
            raise ValueError("threshold_off must be below threshold_on")
        self.heads, self.areas, self.head_tracks = self.layout(track, p)
        self.expected, _ = channel_layout(self.heads)
        self.head_ids = [h["id"] for h in self.heads]
        self.head_pos = np.array([h["position"] for h in self.heads], float)
        self.section_ids = [sid for _, sid, _, _ in self.areas.sections]
        self._monitored = self.areas.monitored()
        self._across = self.areas.across()
        nh = len(self.heads)
        nreg = self.areas.count
        self.count = np.zeros(nreg, dtype=np.int64)
        self.axles_in = np.zeros(nreg, dtype=np.int64)
        self.axles_out = np.zeros(nreg, dtype=np.int64)
        self.disturbed = np.zeros(nreg, dtype=bool)
        if p["start_disturbed"]:
            self.disturbed[list(self._monitored)] = True
        self.last_event: list[tuple[str, int] | None] = [None] * nreg
        self.orient = int(np.sign(p["orientation"])) or None
        self._state = np.zeros(2 * nh, dtype=bool)
        self._last_x = np.zeros(2 * nh)
        self._last_dn = np.full(2 * nh, np.nan)
        self._episodes: list[_Episode | None] = [None] * nh
        self._reported_states: tuple[int, ...] | None = None
        self._last_report: float | None = None
        self._force_report = True
        self._fs = 0.0
        self._pending: dict[int, _Passage] = {}
        self.layout = sorted(float(a) for a in p["axle_offsets"])
        self.stats.update(axles=0, rejected_sequences=0, fixes=0, front_identified_shifted=0, front_inflated=0,
                          front_unidentified=0)

    def layout(self, track: Track, params: dict) -> tuple[list[dict], Areas, list[str]]:
        """(heads, the areas they bound, the track id of each head) of the device: the heads of
        one track (``device_heads``) and the areas between them (a network's device:
        core/network/wayside.py)."""
        heads = device_heads(track, params)
        return heads, Areas.line(heads), [track.track_id] * len(heads)

    # -- public API -------------------------------------------------------------------
    def reset_section(self, section_id: str) -> None:
        """Reset a section (operator command): count zeroed, CLEAR, disturbance cleared.

        Real systems offer a preparatory reset (the section stays occupied until a
        train has swept it); here the reset is direct. KeyError for an unknown id.
        """
        if section_id not in self.section_ids:
            raise KeyError(f"unknown section {section_id!r}; known: {', '.join(self.section_ids)}")
        r = self.areas.sections[self.section_ids.index(section_id)][0]
        self.count[r] = self.axles_in[r] = self.axles_out[r] = 0
        self.disturbed[r] = False
        self.last_event[r] = None
        self._force_report = True

    def section_states(self) -> tuple[int, ...]:
        return tuple(DISTURBED if self.disturbed[r] else OCCUPIED if self.count[r] > 0 else CLEAR
                     for r, *_ in self.areas.sections)

    def occupancy(self, stamp: float) -> SectionOccupancy:
        states = self.section_states()
        sections = tuple(SectionState(sid, start, end, state, int(self.count[r]), int(self.axles_in[r]),
                                      int(self.axles_out[r]))
                         for (r, sid, start, end), state in zip(self.areas.sections, states))
        return SectionOccupancy(float(stamp), self.unit_id, sections)

    # -- decoding ---------------------------------------------------------------------
    def _check(self, block: RawBlock):
        """Channel layout and range check; returns the per-channel minima and maxima of the
        block (lists of floats)."""
        if block.channels != self.expected:
            known = set(self.head_ids)
            for name in block.channels:
                head, _, system = name.rpartition(".")
                if head not in known or system not in ("a", "b"):
                    raise InputRejected("unknown_id", f"channel {name!r} is not a head of this axle counter")
            raise InputRejected("channels", f"channels {block.channels} differ from {self.expected}")
        c_min, c_max = block.data.min(axis=0).tolist(), block.data.max(axis=0).tolist()
        if min(c_min) < -1.0 or max(c_max) > 3.0:
            raise InputRejected("implausible", "normalised damping outside -1..3")
        return c_min, c_max

    def decode(self, block: RawBlock):
        c_min, c_max = self._check(block)
        p = self.params
        self._fs = block.sample_rate
        n = block.data.shape[0]
        dt = 1.0 / block.sample_rate
        t0 = block.t0
        on_thr, off_thr = p["threshold_on"], p["threshold_off"]
        # Usually no wheel is near any head: a system that is free and stays below the
        # on-level, or is damped and stays at or above it, has no switching and no on-level
        # crossing in the block, so there are no events.
        if all(mx < on_thr if not on else mn >= on_thr for mn, mx, on in zip(c_min, c_max, self._state.tolist())):
            self._last_x = block.data[-1].astype(float)
            passages = []
        else:
            passages = self._passages(block, n, dt, t0, on_thr, off_thr)
        out = []
        if self._force_report or self._last_report is None:
            out.append(self.occupancy(t0))
            self._reported_states = self.section_states()
            self._last_report = t0
            self._force_report = False
        passages.sort(key=lambda q: q[0])
        for t_done, hi, d, t_c, v in passages:
            out.extend(self._count(hi, d, t_c, v))
            states = self.section_states()
            if states != self._reported_states:
                out.append(self.occupancy(t_done))
                self._reported_states = states
                self._last_report = t_done
        t_last = t0 + (n - 1) * dt
        for hi in list(self._pending):
            out.extend(self._identify(hi, t_last))
        if t_last - self._last_report >= p["report_period"] - 1e-9:
            out.append(self.occupancy(t_last))
            self._last_report = t_last
        return out

    def _passages(self, block: RawBlock, n: int, dt: float, t0: float, on_thr: float, off_thr: float) -> list:
        """Switching events of the block -> completed axle passages (see _evaluate)."""
        x = block.data.astype(float)
        nc = x.shape[1]
        # hysteresis, vectorised: carry the last defined state forward
        on = x >= on_thr
        defined = on | (x < off_thr)
        idx = np.where(defined, np.arange(n)[:, None], -1)
        idx = np.maximum.accumulate(idx, axis=0)
        state = np.where(idx >= 0, np.take_along_axis(on, np.maximum(idx, 0), axis=0), self._state[None, :])
        full = np.vstack([self._state[None, :], state])
        change = full[1:] != full[:-1]
        # on-level crossings with linear interpolation (prev sample carried over)
        xx = np.vstack([self._last_x[None, :], x])
        dn = (xx[1:] < on_thr) & (xx[:-1] >= on_thr)
        with np.errstate(divide="ignore", invalid="ignore"):
            frac = np.clip((on_thr - xx[:-1]) / (xx[1:] - xx[:-1]), 0.0, 1.0)
        tcross = t0 + (np.arange(n)[:, None] - 1.0 + frac) * dt  # time of a crossing ending at sample i
        events = []  # (sample, order, head, system, kind, time)
        for c in np.flatnonzero(change.any(axis=0)):
            hi, s = divmod(int(c), 2)
            dn_idx = np.flatnonzero(dn[:, c])
            for i in np.flatnonzero(change[:, c]):
                if state[i, c]:
                    events.append((int(i), 0, hi, s, 1, float(tcross[i, c])))
                else:
                    k = np.searchsorted(dn_idx, i, side="right") - 1
                    tf = float(tcross[dn_idx[k], c]) if k >= 0 else float(self._last_dn[c])
                    if not math.isfinite(tf):
                        tf = t0 + (i - 0.5) * dt
                    events.append((int(i), 1, hi, s, 0, tf))
        # remember the last falling crossing of each channel for pulses ending in a later block
        any_dn = dn.any(axis=0)
        if any_dn.any():
            last_dn_i = n - 1 - np.argmax(dn[::-1], axis=0)
            self._last_dn = np.where(any_dn, tcross[last_dn_i, np.arange(nc)], self._last_dn)
        self._state = state[-1].copy()
        self._last_x = x[-1].copy()
        events.sort(key=lambda e: (e[0], e[1]))  # within a sample: switch-on before switch-off
        passages = []
        for i, _, hi, s, kind, t in events:
            ep = self._episodes[hi]
            if kind == 1:
                if ep is None:
                    ep = self._episodes[hi] = _Episode()
                ep.on[s] = True
                if ep.rise[s] is None:
                    ep.rise[s] = t
            else:
                if ep is None:  # switch-off of a pulse started before the decoder did
                    continue
                ep.on[s] = False
                ep.fall[s] = t
                if not (ep.on[0] or ep.on[1]):
                    self._episodes[hi] = None
                    passage = self._evaluate(hi, ep, t0 + i * dt)
                    if passage is not None:
                        passages.append(passage)
        return passages

    def _evaluate(self, hi: int, ep: _Episode, t_done: float):
        """(t_done, head, direction, t_centre, speed) of a valid axle sequence, else None."""
        ra, rb = ep.rise
        fa, fb = ep.fall
        if None in (ra, rb, fa, fb):
            self.stats["rejected_sequences"] += 1
            return None
        if ra < rb and fa < fb:
            d = 1
        elif ra > rb and fa > fb:
            d = -1
        else:
            self.stats["rejected_sequences"] += 1
            return None
        lag = abs((rb + fb) - (ra + fa)) / 2.0
        speed = self.params["sensor_spacing"] / lag if lag > 0 else math.inf
        if speed > self.params["max_speed"]:
            self.stats["rejected_sequences"] += 1
            return None
        return (t_done, hi, d, (ra + fa + rb + fb) / 4.0, speed)

    def _count(self, hi: int, d: int, t_c: float, speed: float):
        p = self.params
        left, right = self.areas.left[hi], self.areas.right[hi]
        src, dst = (left, right) if d > 0 else (right, left)
        into_empty = self.count[dst] == 0 and not self.disturbed[dst]
        self.stats["axles"] += 1
        self.count[src] -= 1
        self.axles_out[src] += 1
        self.count[dst] += 1
        self.axles_in[dst] += 1
        self.last_event[src] = ("out", hi)
        self.last_event[dst] = ("in", hi)
        if src not in self._monitored:
            self.count[src] = max(self.count[src], 0)  # unmonitored area: only what it received is known
        else:
            if self.count[src] < 0:
                self.disturbed[src] = True                      # rule A
            elif self.count[src] == 0:
                for head, q in self._across[src]:               # rule B
                    if q in self._monitored and not self.disturbed[q] and self.count[q] > 0 \
                            and self.last_event[q] == ("out", head):
                        self.disturbed[q] = True
        out = []
        passage = self._pending.get(hi)
        if passage is not None:
            if passage.d == d:
                passage.times.append(t_c)
                passage.speeds.append(speed)
                return self._identify(hi, t_c)
            del self._pending[hi]   # the train reversed over the head before its first axle was identified
            self.stats["front_unidentified"] += 1
        if not into_empty:
            return out
        if p["front_first"]:
            o = d
        else:
            # the train's orientation: that of its first passage, learnt once the passage is
            # identified as a train's (a spurious axle counted first must not set it: _fix)
            o = d if self.orient is None else self.orient
        if d != o and p["last_axle_offset"] <= 0.0:
            return out
        passage = self._pending[hi] = _Passage(hi, d, o)
        passage.times.append(t_c)
        passage.speeds.append(speed)
        return out + self._identify(hi, t_c)

    # -- first-axle identification ----------------------------------------------------
    def _gaps(self, d: int, o: int) -> list[float]:
        """Layout spacings in the order the axles pass a head in direction d (train orientation o)."""
        gaps = np.diff(self.layout).tolist()
        return gaps if d == o else gaps[::-1]

    def _offset(self, d: int, j: int, o: int) -> float:
        """Distance behind the front of the j-th axle to pass a head in direction d (orientation o)."""
        if d == o:
            return self.params["first_axle_offset"] + (self.layout[j] - self.layout[0] if j else 0.0)
        return self.params["last_axle_offset"] - (self.layout[-1] - self.layout[-1 - j] if j else 0.0)

    def _fits(self, passage: _Passage, hyp: tuple[int, int], gaps: list[float], t_now: float) -> bool:
        """Whether the detections of the passage fit the layout under hypothesis hyp."""
        skip, first = hyp
        n = len(passage.times)
        if first >= len(self.layout):
            return False
        for i in range(skip, n - 1):
            j = first + i - skip
            if j >= len(gaps):
                return False   # more axles than the train has
            if abs(passage.spacing(i) - gaps[j]) > GAP_REL * gaps[j] + GAP_ABS or not passage.same_train(i):
                return False
        j = first + n - 1 - skip
        if n > skip and j < len(gaps):   # the next axle of the train is overdue
            v = max(passage.speeds[-1], 0.1)
            if t_now - passage.times[-1] > OVERDUE_REL * gaps[j] / v + OVERDUE_ABS:
                return False
        return True

    def _front_at_first(self, passage: _Passage, hyp: tuple[int, int]) -> float:
        """Front position under hyp at the first detection's time (comparable between hypotheses)."""
        skip, first = hyp
        front = self.head_pos[passage.head] + passage.o * self._offset(passage.d, first, passage.o)
        return float(front - passage.d * passage.advance()) if skip else float(front)

    def _identify(self, hi: int, t_now: float) -> list:
        """Publish or withhold the front fix of the passage at head hi once its first axle is
        identified (or identify_time has run out); [] while it waits."""
        passage = self._pending[hi]
        late = t_now - passage.times[0] >= self.params["identify_time"]
        if not self.layout:
            # No layout: a missed first axle puts the fix off by the first spacing of the train,
            # a spurious axle by the train's advance to its first axle. The fix waits for the
            # second axle and covers the measured spacing; on bogie vehicles the first spacing (the
            # wheelbase) is the shortest of the train, so this covers a missed axle too (not
            # on two-axle wagons with a shorter coupling gap: give the layout there).
            if len(passage.times) < 2 and not late:
                return []
            del self._pending[hi]
            if len(passage.times) < 2:
                self.stats["front_unidentified"] += 1
                return []
            self.stats["front_inflated"] += 1
            return [self._fix(passage, (0, 0), max(passage.spacing(0), passage.advance()))]
        gaps = self._gaps(passage.d, passage.o)
        fitting = [h for h in HYPOTHESES if self._fits(passage, h, gaps, t_now)]
        # Identified: exactly one fitting hypothesis has matched a spacing (and the speeds) of
        # the layout. A hypothesis that explains that spacing away as a spurious axle before
        # the first is not monitored: the spurious axle would have to sit exactly one layout
        # spacing ahead of the train's first axle and move at the train's speed, a coincidence
        # for a count that is unrelated to the train (EMI, a trolley, a track machine).
        matched = [h for h in fitting if len(passage.times) - h[0] >= 2]
        if len(matched) == 1:
            del self._pending[hi]
            if matched[0] != (0, 0):
                self.stats["front_identified_shifted"] += 1
            return [self._fix(passage, matched[0], 0.0)]
        if fitting and not late:
            return []
        del self._pending[hi]
        if not fitting or any(len(passage.times) <= skip for skip, _ in fitting):
            self.stats["front_unidentified"] += 1   # no hypothesis fits, or one has not seen its first axle
            return []
        best = fitting[0]   # the fewest faults
        ref = self._front_at_first(passage, best)
        spread = max(abs(self._front_at_first(passage, h) - ref) for h in fitting)
        if spread > 0.0:
            self.stats["front_inflated"] += 1
        return [self._fix(passage, best, spread)]

    def _fix(self, passage: _Passage, hyp: tuple[int, int], spread: float) -> PositionFix:
        """Front fix at the passage of the first axle under hyp; its stddev covers ``spread``
        (the distance to the fronts of the other hypotheses, measured within the spacing
        tolerance) within COVER sigma."""
        p = self.params
        skip, first = hyp
        hi, d = passage.head, passage.d
        t_c, speed = passage.times[skip], passage.speeds[skip]
        o = passage.o
        if self.orient is None and not p["front_first"]:
            self.orient = o
        offset = self._offset(d, first, o) if self.layout else (p["first_axle_offset"] if d == o
                                                                else p["last_axle_offset"])
        slow = 0.1 if speed < 1.0 else 0.0
        timing = min(speed, p["max_speed"]) * 0.25 / self._fs
        sigma = fix_sigma(p, timing, slow, (spread * (1.0 + GAP_REL) + GAP_ABS) / COVER if spread > 0.0 else 0.0)
        self.stats["fixes"] += 1
        return PositionFix(float(t_c), self.sensor, self.unit_id, self.head_tracks[hi], self.head_ids[hi],
                           float(self.head_pos[hi] + o * offset), sigma, int(d))


def fix_sigma(params: dict, timing: float = 0.0, slow: float = 0.0, cover: float = 0.0) -> float:
    """1-sigma [m] of a front fix: root sum of squares of ``head_position_sigma``,
    ``axle_offset_sigma`` and the decoder's timing, stop-over-the-head and hypothesis-cover terms
    [m], at least MIN_FIX_SIGMA; with those 0 the least a fix reports (the error model's floor)."""
    return max(math.sqrt(params["head_position_sigma"] ** 2 + params["axle_offset_sigma"] ** 2 + timing ** 2
                         + slow ** 2 + cover ** 2), MIN_FIX_SIGMA)


def front_offsets(params: dict) -> tuple[tuple[int, float], ...]:
    """(orientation o, distance behind the front d [m]) of every front fix the decoder can give:
    front = head + o x d (AxleCounterDecoder._fix, _offset). o: ``orientation`` if set and not
    ``front_first``, else +-1. d: the first axle's ``first_axle_offset``, or that plus the first
    layout spacing (first axle missed, hypothesis (0, 1)), when the front leads; the last axle's
    ``last_axle_offset``, or that less the last spacing, when the train backs (only with
    last_axle_offset > 0 and not front_first)."""
    layout = sorted(float(a) for a in params["axle_offsets"])
    leads = [params["first_axle_offset"]]
    backs = [params["last_axle_offset"]] if params["last_axle_offset"] > 0.0 and not params["front_first"] else []
    if len(layout) >= 2:
        leads.append(params["first_axle_offset"] + (layout[1] - layout[0]))
        backs += [b - (layout[-1] - layout[-2]) for b in backs]
    fixed = int(np.sign(params["orientation"]))
    orients = (fixed,) if fixed and not params["front_first"] else (1, -1)
    return tuple((o, d) for o in orients for d in leads + backs)


def error_model(params: dict, track, vehicle) -> ErrorModel:
    """Axle-counter fixes for the fusion: white (head survey, axle offset and edge timing
    in the decoder's stddev); fault modes: a miscount (missed or extra axle), an offset of a run of fixes (a
    head off its surveyed place). Floor: ``fix_sigma``
    without the decoder's terms, max(hypot(head_position_sigma, axle_offset_sigma), 1 mm).
    References: the device's heads (``device_heads``, as the decoder), window the head's chainage +
    o x d over every (o, d) of ``front_offsets``; an empty table if the track has none."""
    references = None
    if track is not None:
        try:
            heads = device_heads(track, params)
        except TrackError:
            heads = []     # the decoder refuses to run on it: no fix is honest
        offs = [o * d for o, d in front_offsets(params)]
        references = ReferenceTable({str(h["id"]): ReferenceWindow(float(h["position"]) + min(offs),
                                                                   float(h["position"]) + max(offs))
                                     for h in heads})
    return ErrorModel("axle_counter", "position", faults=("miscount", "offset"), min_stddev=fix_sigma(params),
                      references=references)


SPEC = SensorSpec(
    node="axle_counter", sensor="axle_counter", simulator=AxleCounterSimulator, decoder=AxleCounterDecoder,
    params=PARAMS, description="wayside axle counter: section occupancy and train-front fixes at the heads",
    seeds=("004",),
    outputs=("position", "sections"), error_model=error_model,
)
