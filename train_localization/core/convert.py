"""Message <-> core conversions, shared by the nodes and the offline (bag) tools.

Reading uses attribute access only, so it works for rclpy messages and for the
objects rosbags deserialises from a bag alike. Writing needs the message classes:
``MsgClasses`` holds them, built either from the generated rclpy modules
(nodes/common.py) or from a rosbags typestore (core/bagio.py).

Stamps are handled in integer nanoseconds: ``stamp_to_sec`` and ``MsgClasses.header``
(through ``sec_to_ns``) are exact inverses for canonical times (``canonical``), so a value that goes
through a message and back is bit-identical.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from .measurements import (Acceleration, DistanceIncrement, PositionFix, SectionOccupancy, SectionState,
                           SpeedMeasurement, YawRate)
from .etcs.records import EventKind, LocationEvent, LocationReport, PathSection, QDirLrbg, Reaction
from .safety.admission import MAX_ITEMS
from .truth import TruthState
from .signals import InputRejected, RawBlock, require_short

NS = 1_000_000_000


def canonical(t: float) -> float:
    """A time rounded to whole nanoseconds [s]: survives a round trip through a stamp."""
    return round(t * NS) / NS


def stamp_to_sec(stamp) -> float:
    return (int(stamp.sec) * NS + int(stamp.nanosec)) / NS


def sec_to_ns(t: float) -> int:
    return int(round(t * NS))


@dataclass
class MsgClasses:
    """Constructors of the message types used; ``array`` makes a primitive array field."""

    Time: Callable
    Header: Callable
    TrainState: Callable
    RawBlock: Callable
    PositionFix: Callable
    SpeedMeasurement: Callable
    DistanceIncrement: Callable
    SectionState: Callable
    SectionOccupancy: Callable
    TrackHypothesis: Callable
    TrackHypotheses: Callable
    SwitchPositions: Callable
    YawRate: Callable
    array: Callable[[np.ndarray, str], Any]
    # an acceleration travels as geometry_msgs/AccelWithCovarianceStamped (``acceleration_from_msg``);
    # accel_body(x [m/s^2], variance [m^2/s^4]) makes its AccelWithCovariance
    AccelWithCovarianceStamped: Callable
    accel_body: Callable[[float, float], Any]

    def header(self, t: float, frame_id: str = ""):
        sec, nanosec = divmod(sec_to_ns(t), NS)
        return self.Header(stamp=self.Time(sec=sec, nanosec=nanosec), frame_id=frame_id)


# ---- raw blocks ---------------------------------------------------------------

def raw_block_from_msg(msg) -> RawBlock:
    """Validated RawBlock from a RawBlock message; raises InputRejected."""
    return RawBlock.from_flat(msg.sensor, msg.unit_id, msg.seq, stamp_to_sec(msg.header.stamp),
                              msg.sample_rate, list(msg.channels), list(msg.units),
                              np.asarray(msg.data, dtype=np.float32))


def raw_block_to_msg(block: RawBlock, mc: MsgClasses, frame_id: str = ""):
    return mc.RawBlock(header=mc.header(block.t0, frame_id or block.unit_id), sensor=block.sensor,
                       unit_id=block.unit_id, seq=block.seq, sample_rate=block.sample_rate,
                       channels=list(block.channels), units=list(block.units),
                       data=mc.array(block.data.reshape(-1), "float32"))


# ---- measurements -------------------------------------------------------------

def measurement_to_msg(m, mc: MsgClasses):
    """Message of a core measurement (type chosen by the measurement's type)."""
    h = mc.header(m.stamp, "map")
    if isinstance(m, PositionFix):
        return mc.PositionFix(header=h, sensor=m.sensor, unit_id=m.unit_id, track_id=m.track_id,
                              reference_id=m.reference_id, position=m.position,
                              position_stddev=m.position_stddev, direction=int(m.direction),
                              residuals=mc.array(np.asarray(m.residuals, dtype=np.float64), "float64"),
                              lateral=m.lateral, lateral_stddev=m.lateral_stddev)
    if isinstance(m, SpeedMeasurement):
        return mc.SpeedMeasurement(header=h, sensor=m.sensor, unit_id=m.unit_id, speed=m.speed,
                                   speed_stddev=m.speed_stddev)
    if isinstance(m, DistanceIncrement):
        return mc.DistanceIncrement(header=h, sensor=m.sensor, unit_id=m.unit_id, duration=m.duration,
                                    distance=m.distance, distance_stddev=m.distance_stddev,
                                    speed=m.speed, speed_stddev=m.speed_stddev)
    if isinstance(m, YawRate):
        return mc.YawRate(header=h, sensor=m.sensor, unit_id=m.unit_id, yaw_rate=m.yaw_rate,
                          yaw_rate_stddev=m.yaw_rate_stddev)
    if isinstance(m, Acceleration):
        return mc.AccelWithCovarianceStamped(header=mc.header(m.stamp, m.unit_id),
                                             accel=mc.accel_body(m.acceleration, m.acceleration_stddev ** 2))
    if isinstance(m, SectionOccupancy):
        return mc.SectionOccupancy(header=h, source=m.source, sections=[
            mc.SectionState(section_id=s.section_id, start=s.start, end=s.end, state=s.state,
                            axle_count=s.axle_count, axles_in=s.axles_in, axles_out=s.axles_out)
            for s in m.sections])
    raise TypeError(f"no message for {type(m).__name__}")


def position_fix_from_msg(msg) -> PositionFix:
    m = PositionFix(stamp_to_sec(msg.header.stamp), msg.sensor, msg.unit_id, msg.track_id,
                    msg.reference_id, float(msg.position), float(msg.position_stddev),
                    int(msg.direction), tuple(float(r) for r in msg.residuals),
                    # fields added with networks (docs/network.md): absent from older bags
                    float(getattr(msg, "lateral", 0.0)), float(getattr(msg, "lateral_stddev", 0.0)))
    m.validate()
    return m


def speed_from_msg(msg) -> SpeedMeasurement:
    m = SpeedMeasurement(stamp_to_sec(msg.header.stamp), msg.sensor, msg.unit_id, float(msg.speed),
                         float(msg.speed_stddev))
    m.validate()
    return m


def distance_from_msg(msg) -> DistanceIncrement:
    m = DistanceIncrement(stamp_to_sec(msg.header.stamp), msg.sensor, msg.unit_id, float(msg.duration),
                          float(msg.distance), float(msg.distance_stddev), float(msg.speed),
                          float(msg.speed_stddev))
    m.validate()
    return m


def yaw_rate_from_msg(msg) -> YawRate:
    m = YawRate(stamp_to_sec(msg.header.stamp), msg.sensor, msg.unit_id, float(msg.yaw_rate),
                float(msg.yaw_rate_stddev))
    m.validate()
    return m


ACCELERATION_SENSOR = "accelerometer"   # the sensor class of an acceleration (its message names none)


def acceleration_from_msg(msg) -> Acceleration:
    """An Acceleration from a geometry_msgs/AccelWithCovarianceStamped: linear.x along the track
    [m/s^2], covariance[0] its variance, header.frame_id the unit; validated (InputRejected)."""
    variance = float(msg.accel.covariance[0])
    m = Acceleration(stamp_to_sec(msg.header.stamp), ACCELERATION_SENSOR, msg.header.frame_id,
                     float(msg.accel.accel.linear.x), math.copysign(math.sqrt(abs(variance)), variance))
    m.validate()
    return m


def occupancy_from_msg(msg) -> SectionOccupancy:
    m = SectionOccupancy(stamp_to_sec(msg.header.stamp), msg.source, tuple(
        SectionState(s.section_id, float(s.start), float(s.end), int(s.state), int(s.axle_count),
                     int(s.axles_in), int(s.axles_out)) for s in msg.sections))
    m.validate()
    return m


# measurement topic suffix (sensors/<sensor>/<suffix>) -> (message type name, parser)
MEASUREMENT_TOPICS = {
    "position": ("PositionFix", position_fix_from_msg),
    "speed": ("SpeedMeasurement", speed_from_msg),
    "distance": ("DistanceIncrement", distance_from_msg),
    "yaw_rate": ("YawRate", yaw_rate_from_msg),
    "acceleration": ("AccelWithCovarianceStamped", acceleration_from_msg),
}
SUFFIX_OF = {PositionFix: "position", SpeedMeasurement: "speed", DistanceIncrement: "distance", YawRate: "yaw_rate",
             Acceleration: "acceleration"}
SECTIONS_TOPIC = "wayside/sections"


def measurement_topic(m) -> str:
    """Relative topic of a measurement: sensors/<sensor>/<kind>, or wayside/sections."""
    if isinstance(m, SectionOccupancy):
        return SECTIONS_TOPIC
    return f"sensors/{m.sensor}/{SUFFIX_OF[type(m)]}"


# ---- train state --------------------------------------------------------------

def truth_from_msg(msg) -> TruthState:
    """The TruthState on the train's own track: a network train's route line (its route
    distance; core/network/path.py route_track), else the track's chainage. A bag recorded before
    the route fields existed has none: its position is then the route distance itself."""
    t = stamp_to_sec(msg.header.stamp)
    direction = int(getattr(msg, "route_direction", 0))
    if getattr(msg, "route_id", "") and direction in (1, -1):
        values = (float(msg.route_distance), direction * float(msg.speed), direction * float(msg.acceleration))
    else:
        values = (float(msg.position), float(msg.speed), float(msg.acceleration))
    if not all(map(math.isfinite, values)):
        raise InputRejected("nan", "ground truth state has NaN/inf fields")
    return TruthState(t, *values)


def truth_to_msg(mc: MsgClasses, state: TruthState, track):
    """ground_truth/state of ``state`` on ``track`` in the fused state's frame: on a network's
    route line (``track.path``, core/network/path.py route_track) the section the front is on
    and its chainage there, speed and acceleration along that chainage, with the route
    (``track.track_id``), the route distance and the route's direction along the section
    (docs/network.md); on a single line its chainage (wrapped on a closed track: the state's
    ``position`` already is)."""
    path = getattr(track, "path", None)
    if path is None:
        return train_state_to_msg(mc, state.stamp, track.track_id, state.position, state.speed, state.acceleration)
    s = state.position + path.begin
    step = path.step_at(s)
    return train_state_to_msg(mc, state.stamp, step.section, step.chainage(s), state.speed * step.direction,
                              state.acceleration * step.direction, route_id=track.track_id,
                              route_distance=state.position, route_direction=step.direction)


def train_state_to_msg(mc: MsgClasses, stamp: float, track_id: str, position: float, speed: float,
                       acceleration: float, position_stddev: float = 0.0, speed_stddev: float = 0.0,
                       position_min: float | None = None, position_max: float | None = None,
                       confidence: float = 1.0, mode: int = 1, sensors=(), track_probability: float = 1.0,
                       route_id: str = "", route_distance: float = math.nan, route_direction: int = 0,
                       path: tuple[float, float, float, int] | None = None):
    """A TrainState message; ``path``: (path_position, path_min, path_max, path_direction) of a
    fused state on a network (msg_defs TrainState.msg), None elsewhere (direction 0: not set).
    Every field is given: a typestore message (core/bagio.py) has no defaults."""
    extra = dict(zip(("path_position", "path_min", "path_max", "path_direction"),
                     path if path is not None else (0.0, 0.0, 0.0, 0)))
    return mc.TrainState(
        header=mc.header(stamp, "map"), track_id=track_id, position=position, speed=speed,
        acceleration=acceleration, position_stddev=position_stddev, speed_stddev=speed_stddev,
        position_min=position if position_min is None else position_min,
        position_max=position if position_max is None else position_max,
        confidence=confidence, mode=mode, sensors=list(sensors), track_probability=track_probability,
        route_id=route_id, route_distance=route_distance, route_direction=route_direction, **extra)


# ---- networks (core/network) --------------------------------------------------

SWITCH_WAYS = ("B1", "B2", "")   # a reported switch position: a way, or "" unknown


def track_hypotheses_to_msg(mc: MsgClasses, est, network_id: str):
    """TrackHypotheses message of a core/network NetworkEstimate (most probable first)."""
    return mc.TrackHypotheses(header=mc.header(est.stamp, "map"), network_id=network_id, hypotheses=[
        mc.TrackHypothesis(track_id=h.track_id, position=h.position, speed=h.speed, position_min=h.position_min,
                           position_max=h.position_max, probability=h.probability, path=list(h.path),
                           path_min=mc.array(np.array([a for a, _ in h.pieces], dtype=float), "float64"),
                           path_max=mc.array(np.array([b for _, b in h.pieces], dtype=float), "float64"))
        for h in est.hypotheses])


def switch_positions_to_msg(mc: MsgClasses, stamp: float, positions: dict[str, str]):
    return mc.SwitchPositions(header=mc.header(stamp), switch_ids=list(positions),
                              positions=[positions[k] for k in positions])


def switch_positions_from_msg(msg, max_switches: int = MAX_ITEMS) -> dict[str, str]:
    """switch -> reported way of a SwitchPositions message; InputRejected for a malformed one,
    and ``too_large`` (before anything is read) for more entries than ``max_switches`` (give
    the network's number of point switches; default MAX_ITEMS)."""
    n = max(len(msg.switch_ids), len(msg.positions))
    if n > max_switches:
        raise InputRejected("too_large", f"SwitchPositions of {n} entries (at most {max_switches})")
    ids, ways = list(msg.switch_ids), list(msg.positions)
    if len(ids) != len(ways):
        raise InputRejected("malformed", f"SwitchPositions with {len(ids)} switch ids and {len(ways)} positions")
    bad = [w for w in ways if w not in SWITCH_WAYS]
    if bad:
        raise InputRejected("implausible", f"switch position {bad[0][:16]!r} is not B1, B2 or '' (unknown)")
    require_short("SwitchPositions", **{f"switch_ids[{i}]": k for i, k in enumerate(ids)})
    return dict(zip(ids, ways))


def network_switch_positions(msg, network) -> dict[str, str]:
    """``switch_positions_from_msg`` for the point switches of ``network`` (core/network Network):
    InputRejected ``unknown_id`` as well for a switch that is none of them."""
    switches = {n.node_id for n in network.switches()}
    positions = switch_positions_from_msg(msg, len(switches))
    unknown = [k for k in positions if k not in switches]
    if unknown:
        raise InputRejected("unknown_id", f"switch {unknown[0][:64]!r} is no point switch of network "
                                          f"{network.network_id}")
    return positions


# ---- ETCS location (core/etcs) ------------------------------------------------

CLAIMED_MODES = (1, 2)   # TrainState.MODE_NOMINAL, MODE_DEGRADED


def etcs_report_from_msg(msg, orientation: int = 1) -> LocationReport:
    """The LocationReport of an EtcsLocation message; InputRejected (a ValueError: ``nan``,
    ``implausible``) for a report that cannot be used."""
    t = stamp_to_sec(msg.header.stamp)
    claimed = msg.mode in CLAIMED_MODES
    lo, est, hi = float(msg.min_safe_front_end), float(msg.estimated_front_end), float(msg.max_safe_front_end)
    v, v_ura = float(msg.v_est), float(msg.v_ura)
    if claimed:
        if not all(math.isfinite(x) for x in (lo, est, hi)):
            raise InputRejected("nan", f"front ends {lo} / {est} / {hi} m are not finite in a claimed position")
        if orientation * (hi - lo) < 0.0:
            raise InputRejected("implausible", f"min safe front end {lo:.3f} m is ahead of the max safe "
                                               f"front end {hi:.3f} m")
        if not (math.isfinite(v) and math.isfinite(v_ura)):
            raise InputRejected("nan", f"speed {v} +- {v_ura} m/s is not finite in a claimed position")
    if v_ura < 0.0 or msg.l_doubtover < 0.0 or msg.l_doubtunder < 0.0:
        raise InputRejected("implausible", f"negative v_ura {v_ura} or doubts {msg.l_doubtover} / "
                                           f"{msg.l_doubtunder}")
    try:
        q_dir = QDirLrbg(msg.q_dirlrbg)
    except ValueError:
        raise InputRejected("implausible", f"q_dirlrbg {msg.q_dirlrbg} is not one of Q_DIRLRBG_*") from None
    return LocationReport(t, msg.track_id, msg.nid_lrbg, float(msg.d_lrbg), q_dir, float(msg.q_locacc),
                          float(msg.l_doubtover), float(msg.l_doubtunder), est, lo, hi, v, v_ura,
                          bool(msg.odometer_impaired), tuple(msg.previous_lrbgs), int(msg.mode),
                          str(getattr(msg, "lrbg_track_id", "")), _report_path(msg))


def _report_path(msg) -> tuple[PathSection, ...]:
    """The followed path of an EtcsLocation on a network (empty on a single line, or from a
    message without the fields); InputRejected for arrays of unequal or too many items, a
    direction that is not +-1 or an origin that is not finite."""
    sections = list(getattr(msg, "path", ()))
    directions, origins = list(getattr(msg, "path_direction", ())), list(getattr(msg, "path_origin", ()))
    n = max(len(sections), len(directions), len(origins))
    if n > MAX_ITEMS:
        raise InputRejected("too_large", f"a followed path of {n} sections (at most {MAX_ITEMS})")
    if not len(sections) == len(directions) == len(origins):
        raise InputRejected("malformed", f"path of {len(sections)} sections, {len(directions)} directions and "
                                         f"{len(origins)} origins")
    if any(int(d) not in (1, -1) for d in directions) or not all(math.isfinite(float(o)) for o in origins):
        raise InputRejected("implausible", "a path direction that is not +1 or -1, or an origin that is not finite")
    return tuple(PathSection(str(sid), int(d), float(o)) for sid, d, o in zip(sections, directions, origins))


def etcs_event_from_msg(msg) -> LocationEvent:
    """The LocationEvent of an EtcsEvent message (InputRejected ``unknown`` for an unknown kind
    or reaction)."""
    try:
        kind, reaction = EventKind(msg.kind), Reaction(msg.reaction)
    except ValueError:
        raise InputRejected("unknown", f"kind {msg.kind} / reaction {msg.reaction} unknown") from None
    return LocationEvent(stamp_to_sec(msg.header.stamp), kind, msg.nid_bg, reaction, msg.detail)
