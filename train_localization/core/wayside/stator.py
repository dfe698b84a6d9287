"""Sectional feeding of a long-stator guideway (seed 000 section 2): which stator sections
are connected to their inverters, decided from the fused train state and its interval, and
what that costs or risks on the true motion.

Seed 000 section 2: a long-stator linear synchronous motor must be fed at the frequency of
the vehicle's speed and position; rather than feeding the whole line, the guideway is cut
into power-supply sections slightly longer than the train and only the section where the
train is gets power (sectional feeding control); hence accurate position and speed. Seed
000 section 3 (TR-07): the position goes by mm-wave radio to the control centre, which sets
the inverters' current, frequency and the switching times of the section changes.

Layout. The track lists the sections as equipment of kind ``stator_section`` (start
``position``, ``end`` or ``length``, optional ``inverter``); without an ``inverter`` key,
section k (by chainage) is fed by inverter ``INV{k mod inverters + 1}``: with the default
two inverters the sections alternate (the alternate-step method: the next section is
switched on by the other inverter while the train still draws from the current one)::

    stator_section:
      - {every: 300.0, start: 0.0, end: 29700.0, id: "ST{n:03d}", length: 300.0}

An inverter feeds at most one section at a time; sections must not overlap.

Controller (``StatorController``, the ``stator_section_controller`` node's core). Each
train's states are admitted first (``admit``; below). Every ``period`` the controller forms,
for every state of the train admitted within ``max_state_age`` (not only the latest), the
span the train can occupy until a command decided now has taken effect: where that state
allows the front to be now (its interval moved over its age by its speed interval and
``max_acceleration``, as the plausibility gate's reach, core/safety/plausibility.py), then
each end moved outwards only by the extreme of the speed interval (widened by
``max_acceleration`` over the age) over h = ``command_latency`` + ``switch_time`` + ``period``
(the span is never narrowed by the motion during h), from the min safe rear end (the vehicle's length behind the front) to the max
safe front end, and ``margin`` beyond. The sections the union of these spans overlaps must be
fed; others are switched off. So the next section is fed before the max safe front end can
reach it, the last one is switched off only after the min safe rear end has left it, and a
section stays fed while any admitted state may place the vehicle on it. A section whose
inverter still feeds another needed section waits (``inverter_busy``; the inverter is free
once that section's switch has opened). A train with no claimed position admitted within
``max_state_age`` (initialising, lost, silent) or whose stream is stale (nothing admitted for
``input_timeout``, refused and silent alike) holds: what it needed when last seen stays fed,
nothing is switched on or off for it.

Admission (``TrainStates``: core/safety's StateStream, EN 50159's threats as in
core/safety/admission.py): a state whose stamp is not finite or whose claimed interval or
speed is NaN (``nan``); an interval reaching more than ``track_margin`` beyond the track's
ends, wider than ``max_interval_width``, upside down, a speed beyond MAX_SPEED or a speed
1-sigma beyond it (``implausible``); a stamp more than ``future_tolerance`` ahead of the
consumer's clock (``future``), equal to (``duplicate``) or before (``stamp_back``) the last
admitted one; a claimed state out of kinematic reach of the last admitted one (``motion``,
core/safety/plausibility.py): each is refused, counted and changes nothing. Only an admitted
state moves the stream on, so spoofed states (another position, a standstill, an interval of
the whole line) are refused against the real stream and never replace it. A state that claims
no position is admitted on its stamp alone and is no reference.

Evaluation (``evaluate``) on the true motion: thrust lost (part of the vehicle over an
unfed section), switchings under the vehicle (a switch that closes or opens while the
vehicle is over its section: the switch carries the motor current, and a late switch-on
follows a thrust loss), and an inverter feeding two sections. The motion is the scenario's
(open loop): a thrust loss is counted, not simulated as a deceleration.
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np
from scipy.special import ndtri

from ..measurements import MAX_SPEED
from ..safety import admission, plausibility, state_stream
from ..sensors.base import Param, check_declared, resolve_params
from ..signals import InputRejected
from ..track import Track, TrackError, extent

KIND = "stator_section"
FEED_TOPIC = "stator/feed"
EVENT_GRID = 0.005   # [s] time grid of the evaluation (0.7 m at 500 km/h)

PARAMS = {
    "inverters": Param(2, "inverters feeding the sections in turn where a section names none [1] (2: the "
                          "alternate-step method)", (1, 16)),
    "command_latency": Param(0.05, "from the decision to the section switch receiving the command [s] (radio "
                                   "and wayside network; assumption)", (0.0, 5.0)),
    "switch_time": Param(0.1, "a section switch closing or opening after the command [s] (vacuum switch; "
                              "assumption)", (0.0, 5.0)),
    "period": Param(0.01, "decision period of the controller [s]", (0.001, 1.0)),
    "margin": Param(2.0, "distance added beyond each end of a train's span [m]", (0.0, 1000.0)),
    "speed_confidence": Param(0.999, "probability of the speed interval speed +- k speed_stddev used to "
                                     "move the span over the horizon [1]", (0.5, 0.999999)),
    "max_state_age": Param(0.5, "the spans of every state of a train admitted within this age are fed (their "
                                "union); with no claimed state that young the train holds: nothing switched for "
                                "it [s]", (0.01, 60.0)),
    "track_margin": Param(1000.0, "a claimed interval reaching further than this beyond the track's ends is "
                                  "refused (implausible) [m]", (0.0, 1.0e6)),
    "max_interval_width": Param(2000.0, "a claimed interval wider than this is refused (implausible): no "
                                        "inverters could feed it, and it would let any state through the "
                                        "kinematic gate [m]", (1.0, 1.0e6)),
    **admission.PARAMS,
    **plausibility.PARAMS,
}
MAX_WINDOW = 1000     # admitted states kept per train (a flood of plausible states cannot grow it)
check_declared(PARAMS, "stator_section_controller")


def controller_params(overrides: dict | None = None) -> dict:
    """PARAMS at their defaults updated by ``overrides`` (ValueError in one line)."""
    return resolve_params(PARAMS, overrides)


class StatorError(ValueError):
    """A stator layout that cannot be used, with the reason."""


@dataclass(frozen=True)
class Section:
    """One stator section: chainages [m] and its inverter."""

    section_id: str
    start: float
    end: float
    inverter: str


@dataclass(frozen=True)
class Layout:
    """The stator sections of a track, by chainage."""

    sections: tuple[Section, ...]
    starts: np.ndarray = field(repr=False, compare=False)
    ends: np.ndarray = field(repr=False, compare=False)

    @classmethod
    def of(cls, sections) -> "Layout":
        sections = tuple(sorted(sections, key=lambda s: s.start))
        for a, b in zip(sections, sections[1:]):
            if b.start < a.end - 1e-9:
                raise StatorError(f"{KIND} '{a.section_id}' ({a.start:g}..{a.end:g} m) overlaps "
                                  f"'{b.section_id}' ({b.start:g}..{b.end:g} m)")
        return cls(sections, np.array([s.start for s in sections]), np.array([s.end for s in sections]))

    @classmethod
    def from_track(cls, track: Track, inverters: int = 2) -> "Layout":
        """The track's ``stator_section`` items (StatorError with the reason)."""
        if inverters < 1:
            raise StatorError(f"inverters must be >= 1, not {inverters}")
        items = sorted(track.items(KIND), key=lambda it: float(it.get("start", it["position"])))
        sections = []
        for k, it in enumerate(items):
            try:
                start, end = extent(KIND, it)
            except TrackError as exc:
                raise StatorError(str(exc)) from None
            if not end > start:
                raise StatorError(f"{KIND} '{it['id']}' ends at {end:g} m, not after its start {start:g} m")
            sections.append(Section(str(it["id"]), start, end, str(it.get("inverter", f"INV{k % inverters + 1}"))))
        if len({s.section_id for s in sections}) != len(sections):
            raise StatorError(f"{KIND} ids are not unique on track {track.track_id}")
        return cls.of(sections)

    def __len__(self) -> int:
        return len(self.sections)

    def overlapping(self, lo: float, hi: float) -> range:
        """Indices of the sections that overlap the chainages (lo, hi)."""
        first = int(np.searchsorted(self.ends, lo, side="right"))
        last = int(np.searchsorted(self.starts, hi, side="left"))
        return range(first, max(first, last))


def lay_sections(start: float, end: float, length: float, prefix: str = "ST") -> list[dict]:
    """Track items of contiguous sections of ``length`` [m] from ``start`` to ``end`` (the
    last one ends at ``end``), ids ``{prefix}{n:03d}``."""
    edges = np.arange(start, end, length).tolist()
    if len(edges) > 1 and end - edges[-1] < 0.5 * length:
        edges.pop()        # a short remainder joins the last section
    return [{"id": f"{prefix}{n:03d}", "position": float(a), "end": float(b)}
            for n, (a, b) in enumerate(zip(edges, edges[1:] + [end]))]


def min_section_length(params: dict, vehicle_length: float, max_speed: float, interval_width: float,
                       state_age: float) -> float:
    """Least section length [m] with which the controller never waits for an inverter at
    ``max_speed`` [m/s] (two inverters): while the vehicle, its interval (``interval_width``
    [m]) and the margins fit in one section, the last section's switch opens and the next
    one's closes, each ``command_latency`` + ``switch_time`` after its decision, and the next
    is decided a horizon (``state_age`` [s] + that delay + ``period``) before the max safe
    front end can reach it."""
    delay = params["command_latency"] + params["switch_time"]
    horizon = state_age + delay + params["period"]
    return vehicle_length + interval_width + 2.0 * params["margin"] + max_speed * (delay + horizon + params["period"])


@dataclass(frozen=True)
class TrainView:
    """What the controller takes of one TrainState: stamp [s], whether the position is
    claimed (mode NOMINAL or DEGRADED), the interval of the front [m], speed and its 1-sigma
    [m/s]."""

    stamp: float
    claimed: bool
    position_min: float
    position_max: float
    speed: float
    speed_stddev: float


@dataclass(frozen=True)
class Vehicle:
    """A train as the controller sees it: length [m] behind the front and orientation (+1:
    the front faces increasing chainage)."""

    length: float
    orientation: int = 1


@dataclass(frozen=True)
class Command:
    """Connect (on) or disconnect a section, decided at ``stamp`` [s]; the switch has done it
    at ``effective`` [s]."""

    stamp: float
    effective: float
    section: str
    on: bool


class TrainStates:
    """The admitted states of one train: its core/safety StateStream (the stream's checks, then
    the kinematic gate) and the claimed states admitted within ``max_state_age`` (``window``, at
    most MAX_WINDOW)."""

    def __init__(self, name: str, params: dict, k_speed: float, extent: tuple[float, float]):
        self.params, self.k_speed = params, k_speed
        self.stream = state_stream.StateStream(name, admission.limits_from(params),
                                               plausibility.MotionGate.from_params(params))
        m = params["track_margin"]
        self.limits = {"position_min": (extent[0] - m, extent[1] + m), "position_max": (extent[0] - m, extent[1] + m),
                       "interval_width": (0.0, params["max_interval_width"]), "speed": state_stream.SPEED,
                       "speed_stddev": (0.0, MAX_SPEED)}
        self.window: deque[TrainView] = deque(maxlen=MAX_WINDOW)

    def admit(self, view: TrainView, now: float | None) -> InputRejected | None:
        """Admit ``view`` at the consumer's clock ``now`` [s] (None or 0: none yet; the state's
        own stamp stands for it, so nothing is compared with a clock): None, or the refusal
        (counted in ``stream.refused``)."""
        if view.claimed:
            checks = {"values": {"position_min": view.position_min, "position_max": view.position_max,
                                 "interval_width": view.position_max - view.position_min, "speed": view.speed,
                                 "speed_stddev": view.speed_stddev}, "limits": self.limits}
        else:                    # no claim: its interval and speed mean nothing (a LOST state's is infinite)
            checks = {}
        motion = plausibility.Motion.of(view.stamp, view.claimed, view.position_min, view.position_max, view.speed,
                                        self.k_speed * view.speed_stddev)
        refused = self.stream.admit(motion, now or view.stamp, **checks)
        if refused is None and view.claimed:
            self.window.append(view)
        return refused

    def young(self, now: float) -> list[TrainView]:
        """The claimed states admitted that are at most ``max_state_age`` old at ``now`` [s]
        (older ones are dropped)."""
        while self.window and now - self.window[0].stamp > self.params["max_state_age"]:
            self.window.popleft()
        return list(self.window)


class StatorController:
    """See the module doc. ``admit(name, view, now)`` takes a train's state through its
    admission; ``update(now)`` returns the commands decided now from the admitted states.
    ``extent``: the track's chainages (lo, hi) [m] an interval may reach ``track_margin``
    beyond (default: the layout's)."""

    def __init__(self, layout: Layout, vehicles: dict[str, Vehicle], overrides: dict | None = None,
                 extent: tuple[float, float] | None = None):
        self.layout = layout
        self.vehicles = dict(vehicles)
        self.params = p = controller_params(overrides)
        self.k_speed = float(ndtri(0.5 * (1.0 + p["speed_confidence"])))
        self.delay = p["command_latency"] + p["switch_time"]
        if extent is None:
            extent = (float(layout.starts[0]), float(layout.ends[-1])) if len(layout) else (-math.inf, math.inf)
        self.trains = {name: TrainStates(name, p, self.k_speed, extent) for name in self.vehicles}
        self.fed: set[int] = set()                  # sections commanded on (indices)
        self.released: dict[str, float] = {}        # inverter -> when its last switch-off takes effect [s]
        self.inverter_of = [s.inverter for s in layout.sections]
        self.held: dict[str, set[int]] = {}         # train -> sections it needed when it was last seen
        self.stale: set[str] = set()                # trains whose stream is stale (at the last update)
        self.commands: list[Command] = []
        self.counters = {"decisions": 0, "switch_on": 0, "switch_off": 0, "inverter_busy": 0, "held": 0,
                         "stale": 0}

    def admit(self, name: str, view: TrainView, now: float | None) -> InputRejected | None:
        """Train ``name``'s state through its admission (TrainStates.admit): None, or the refusal."""
        return self.trains[name].admit(view, now)

    def latest_stamp(self) -> float | None:
        """The newest stamp admitted of any train [s] (None before any)."""
        stamps = [tr.stream.stream.last_stamp for tr in self.trains.values() if tr.stream.stream.last_stamp is not None]
        return max(stamps) if stamps else None

    def spans(self, views, vehicle: Vehicle, now: float) -> tuple[np.ndarray, np.ndarray]:
        """Chainages (lo, hi) [m] the train can occupy, by each of ``views``, until a command
        decided at ``now`` has taken effect: where the state allows the front to be now (its
        reach over its age: plausibility's, with ``max_acceleration`` and MAX_SPEED), moved by
        the speed interval's extreme over command_latency + switch_time + period away from the
        train only, the vehicle behind the front, ``margin`` beyond."""
        p = self.params
        a = p["max_acceleration"]
        t = np.array([view.stamp for view in views], float)
        lo = np.array([view.position_min for view in views], float)
        hi = np.array([view.position_max for view in views], float)
        speed = np.array([view.speed for view in views], float)
        bound = self.k_speed * np.array([view.speed_stddev for view in views], float)
        age = np.maximum(now - t, 0.0)
        front_lo, front_hi = plausibility.reach_bounds(lo, hi, speed - bound, speed + bound, age, a)
        h = self.delay + p["period"]
        front_lo = front_lo + np.minimum(speed - bound - a * age, 0.0) * h
        front_hi = front_hi + np.maximum(speed + bound + a * age, 0.0) * h
        if vehicle.orientation > 0:
            front_lo = front_lo - vehicle.length
        else:
            front_hi = front_hi + vehicle.length
        return front_lo - p["margin"], front_hi + p["margin"]

    def span(self, view: TrainView, vehicle: Vehicle, now: float) -> tuple[float, float]:
        """The span (spans) of one state [m]."""
        lo, hi = self.spans([view], vehicle, now)
        return float(lo[0]), float(hi[0])

    def sections_of(self, views, vehicle: Vehicle, now: float) -> set[int]:
        """Indices of the sections the union of the states' spans overlaps."""
        lo, hi = self.spans(views, vehicle, now)
        first = np.searchsorted(self.layout.ends, lo, side="right")
        last = np.maximum(np.searchsorted(self.layout.starts, hi, side="left"), first)
        out: set[int] = set()
        for f, g in set(zip(first.tolist(), last.tolist())):
            out.update(range(f, g))
        return out

    def needed(self, now: float) -> set[int]:
        """Sections that must be fed: those the union of each train's admitted states' spans
        overlaps, and what a holding train (stale, or no claimed state within max_state_age)
        needed when last seen."""
        need: set[int] = set()
        self.stale = set()
        for name, vehicle in self.vehicles.items():
            train = self.trains[name]
            if train.stream.admitted and train.stream.stale(now):
                self.stale.add(name)
                self.counters["stale"] += 1
                views = []
            else:
                views = train.young(now)
            if views:
                self.held[name] = self.sections_of(views, vehicle, now)
            elif name in self.held:
                self.counters["held"] += 1
            need |= self.held.get(name, set())
        return need

    def update(self, now: float) -> list[Command]:
        self.counters["decisions"] += 1
        need = self.needed(now)
        out = [self._switch(now, k, False) for k in sorted(self.fed - need)]
        busy = {self.inverter_of[k] for k in self.fed}
        for k in sorted(need - self.fed):
            inv = self.inverter_of[k]
            if inv in busy or self.released.get(inv, -math.inf) > now:
                self.counters["inverter_busy"] += 1
                continue
            out.append(self._switch(now, k, True))
            busy.add(inv)
        self.commands.extend(out)
        return out

    def _switch(self, now: float, k: int, on: bool) -> Command:
        if on:
            self.fed.add(k)
        else:
            self.fed.discard(k)
            self.released[self.inverter_of[k]] = now + self.delay
        self.counters["switch_on" if on else "switch_off"] += 1
        return Command(now, now + self.delay, self.layout.sections[k].section_id, on)

    def fed_sections(self) -> list[str]:
        """Ids of the sections commanded on, by chainage."""
        return [self.layout.sections[k].section_id for k in sorted(self.fed)]

    def refused(self) -> dict[str, int]:
        """Refusals by reason over every train's stream."""
        out: dict[str, int] = {}
        for train in self.trains.values():
            for reason, n in train.stream.refused.items():
                out[reason] = out.get(reason, 0) + n
        return out


def run_controller(layout: Layout, vehicle: Vehicle, series, overrides: dict | None = None,
                   name: str = "train", extent: tuple[float, float] | None = None) -> StatorController:
    """The controller stepped every ``period`` over one train's fused states (a
    scoring.StateSeries: t, position_min/max, speed, speed_stddev, mode): before each decision
    every state stamped at or before it is admitted (at the decision's time), as the node
    admits each state that arrives."""
    ctrl = StatorController(layout, {name: vehicle}, overrides, extent)
    t = np.asarray(series.t, float)
    if not t.size:
        return ctrl
    claimed = np.isin(np.asarray(series.mode), (1, 2)).tolist()
    lo, hi = np.asarray(series.position_min, float).tolist(), np.asarray(series.position_max, float).tolist()
    v, sv = np.asarray(series.speed, float).tolist(), np.asarray(series.speed_stddev, float).tolist()
    stamps = t.tolist()
    period = ctrl.params["period"]
    j = 0
    for now in np.arange(t[0], t[-1] + 1e-9, period).tolist():
        while j < len(stamps) and stamps[j] <= now + 1e-9:
            ctrl.admit(name, TrainView(stamps[j], claimed[j], lo[j], hi[j], v[j], sv[j]), now)
            j += 1
        ctrl.update(now)
    return ctrl


def commands_from_feed(feeds, delay: float) -> list[Command]:
    """The commands behind a recorded feed stream: ``feeds`` (stamp [s], fed section ids) in
    time order, as the controller publishes them on every change; each change is a command
    decided at its stamp, effective ``delay`` [s] (command_latency + switch_time) later."""
    out, fed = [], set()
    for stamp, ids in feeds:
        now = set(ids)
        out += [Command(stamp, stamp + delay, sid, False) for sid in sorted(fed - now)]
        out += [Command(stamp, stamp + delay, sid, True) for sid in sorted(now - fed)]
        fed = now
    return out


@dataclass
class StatorReport:
    """What the feeding did on the true motion of one train (seconds, counts)."""

    thrust_loss_s: float = 0.0            # time with part of the vehicle over an unfed section
    thrust_deficit_s: float = 0.0         # integral of the unfed share of the vehicle's length
    # (time, section, "on"/"off"): "off" cut the motor current under the vehicle (the hazard);
    # "on" closed late, onto a section the vehicle had reached unfed (thrust lost before)
    switched_under_vehicle: list = field(default_factory=list)
    double_feed: list = field(default_factory=list)              # (time, inverter, sections)
    section_passages: int = 0             # sections the vehicle's front entered
    switchings: int = 0
    startup_s: float = 0.0                # from the motion's start until the first commands took effect

    def as_dict(self) -> dict:
        off = sum(1 for e in self.switched_under_vehicle if e[2] == "off")
        return {"thrust_loss_s": self.thrust_loss_s, "thrust_deficit_s": self.thrust_deficit_s,
                "switched_under_vehicle": len(self.switched_under_vehicle),
                "switched_off_under_vehicle": off, "switched_on_late": len(self.switched_under_vehicle) - off,
                "switched_under_vehicle_list": [list(e) for e in self.switched_under_vehicle[:20]],
                "double_feed": len(self.double_feed), "section_passages": self.section_passages,
                "switchings": self.switchings, "startup_s": self.startup_s,
                "thrust_loss_per_passage_s": (self.thrust_loss_s / self.section_passages
                                              if self.section_passages else None)}


def evaluate(layout: Layout, commands: list[Command], times, front, vehicle: Vehicle) -> StatorReport:
    """Events of the commands on the true motion: ``front`` [m] true front chainage at
    ``times`` [s] (resampled on EVENT_GRID); the vehicle occupies ``vehicle.length`` behind it.

    The scored time starts when the first commands have taken effect: before, the controller
    had no position yet (the sections fed then are the business of whatever fed the line
    before it; ``startup_s``); without commands nothing is scored."""
    times, front = np.asarray(times, float), np.asarray(front, float)
    rep = StatorReport(switchings=len(commands))
    if times.size < 2 or not len(layout) or not commands:
        return rep
    start = max(min(c.effective for c in commands), float(times[0]))
    rep.startup_s = start - float(times[0])
    if start >= times[-1]:
        return rep
    grid = np.arange(start, times[-1] + 1e-9, EVENT_GRID)
    x = np.interp(grid, times, front)
    tail = x - vehicle.orientation * vehicle.length
    lo, hi = np.minimum(x, tail), np.maximum(x, tail)
    unfed = np.zeros(grid.size)
    by_section: dict[str, list[Command]] = {}
    for c in commands:
        by_section.setdefault(c.section, []).append(c)
    for k, sec in enumerate(layout.sections):
        overlap = np.clip(np.minimum(hi, sec.end) - np.maximum(lo, sec.start), 0.0, None)
        if not overlap.any():
            continue
        cmds = sorted(by_section.get(sec.section_id, ()), key=lambda c: c.effective)
        eff = np.array([c.effective for c in cmds])
        state = np.array([c.on for c in cmds] or [False])
        idx = np.searchsorted(eff, grid, side="right") - 1
        fed = np.where(idx >= 0, state[np.maximum(idx, 0)], False)
        unfed += np.where(fed, 0.0, overlap)
        for c in cmds:
            if start < c.effective <= times[-1]:
                xe = float(np.interp(c.effective, times, front))
                te = xe - vehicle.orientation * vehicle.length
                if min(sec.end, max(xe, te)) - max(sec.start, min(xe, te)) > 0.0:
                    rep.switched_under_vehicle.append((c.effective, sec.section_id, "on" if c.on else "off"))
    rep.thrust_loss_s = float(EVENT_GRID * np.count_nonzero(unfed > 1e-9))
    rep.thrust_deficit_s = float(EVENT_GRID * np.sum(unfed) / vehicle.length) if vehicle.length > 0 else 0.0
    ahead = np.searchsorted(layout.starts, x, side="right")
    rep.section_passages = int(np.count_nonzero(np.diff(ahead)))
    rep.double_feed = _double_feed(layout, commands)
    rep.switched_under_vehicle.sort()
    return rep


def _double_feed(layout: Layout, commands: list[Command]) -> list:
    """(time, inverter, sections) where a switch closed while its inverter fed another section."""
    inverter = {s.section_id: s.inverter for s in layout.sections}
    fed: dict[str, set[str]] = {}
    out = []
    for c in sorted(commands, key=lambda c: (c.effective, c.on)):   # an opening first at equal times
        on = fed.setdefault(inverter[c.section], set())
        if c.on:
            if on - {c.section}:
                out.append((c.effective, inverter[c.section], sorted(on | {c.section})))
            on.add(c.section)
        else:
            on.discard(c.section)
    return out
