"""What the ETCS consumers admit (docs/reliability.md): the etcs_location's fused states and
balise fixes, the atp_supervision's location reports and events, through the shared admission
of core/safety. The nodes and the offline closed loop (supervised_run.py) use the same classes,
so the randomised campaign exercises the checks the live nodes run.

Fused states and location reports: the stream's checks (stamps against the consumer's clock
and the last admitted one, non-finite values, sizes) and the kinematic plausibility (a state or
report whose interval or speed the last admitted one rules out: ``motion``). Balise fixes:
the stream's checks but their order (a fix comes up to the reader's latency after its stamp, so
one spoofed fix stamped now must not make the real ones late; the location function sorts them
and refuses one older than its history), and load shedding (``max_input_rate`` per topic, as the fusion's inputs:
``shed``), so a flood of reads cannot delay the reports. Events are not ordered (a missed group's
event is stamped at its window's closing) and only checked for time, values and sizes: an event
can only ask for a brake, so an inserted one costs availability, never safety.
"""
from __future__ import annotations

from ..fusion.shedding import InputShedder
from ..measurements import PositionFix
from ..safety import admission, plausibility
from ..safety.admission import StreamAdmission, StreamLimits
from ..safety.plausibility import Motion, MotionGate, speed_bound
from ..safety.state_stream import CHAINAGE, SPEED, StateStream, claim_checks
from ..sensors.base import Param, check_declared, resolve_params
from ..signals import InputRejected
from .location import PREVIOUS_LRBGS, FusedState
from .records import LocationEvent, LocationReport

PARAMS = {
    **admission.PARAMS,
    **plausibility.PARAMS,
    "max_input_rate": Param(1000.0, "fused states or reports per second taken on average; beyond it they are "
                                    "shed (counted) [1/s]", (1.0, 1.0e6)),
    "max_fix_rate": Param(100.0, "balise fixes per second taken on average, bursts of a quarter of a second's "
                                 "worth (a group of up to 8 balises reads within milliseconds; at 500 km/h and a "
                                 "group every 100 m a reader gives about 12 a second); beyond it they are shed "
                                 "before they are parsed (counted) [1/s]", (1.0, 1.0e6)),
}
check_declared(PARAMS, "etcs admission PARAMS")
STATE_TOPIC, FIX_TOPIC = "localization/state", "sensors/eurobalise/position"   # the location's inputs


def admission_params(overrides: dict | None = None) -> dict:
    """PARAMS at their defaults updated by ``overrides`` (ValueError in one line); other keys of
    ``overrides`` are ignored."""
    return resolve_params(PARAMS, {k: v for k, v in (overrides or {}).items() if k in PARAMS})


class LocationAdmission:
    """The etcs_location's inputs: ``state(s, now)`` and ``fix(f, now)`` return None (admitted)
    or the refusal; a fix must name ``track_id`` or, on a network, one of its ``sections``; ``now``: the node's clock [s] (0/None: none yet); ``host_now``: the clock
    shedding counts on (the host's monotonic clock live, the consumer clock offline)."""

    def __init__(self, params: dict | None = None, track_id: str = "", sections=None):
        p = self.params = admission_params(params)
        self.track_id = track_id
        self.sections = frozenset(sections) if sections else frozenset((track_id,))   # a fix's track: one of these
        self.states = StateStream(STATE_TOPIC, admission.limits_from(p), MotionGate.from_params(p))
        # fixes arrive up to the reader's latency after their stamp, in any order with a spoofed
        # one stamped now: not ordered (the location function sorts them and refuses a too old one)
        self.fixes = StreamAdmission(FIX_TOPIC, admission.limits_from(p, ordered=False))
        self.shedder = InputShedder(float(p["max_input_rate"]))
        self.fix_shedder = InputShedder(float(p["max_fix_rate"]))

    def shed(self, topic: str, host_now: float) -> bool:
        """True when a message of ``topic`` is to be shed (counted in ``shed_counts``)."""
        shedder = self.fix_shedder if topic == self.fixes.name else self.shedder
        return not shedder.admit(topic, host_now)

    @property
    def shed_counts(self) -> dict[str, int]:
        """Messages shed by topic."""
        return {**self.shedder.shed, **self.fix_shedder.shed}

    def state(self, s: FusedState, now: float | None) -> InputRejected | None:
        checks = {}
        if s.claimed:       # its numbers those of a train, its position inside its interval
            checks = claim_checks(s)
            checks["limits"]["position"] = (s.position_min, s.position_max)
        motion = Motion.of(s.t, s.claimed, s.position_min, s.position_max, s.speed,
                           speed_bound(s.confidence, s.speed_stddev) if s.claimed else 0.0)
        return self.states.admit(motion, now, **checks)

    def fix(self, f: PositionFix, now: float | None) -> InputRejected | None:
        if f.track_id not in self.sections:
            where = f"this is {self.track_id!r}" if len(self.sections) == 1 else f"no section of {self.track_id!r}"
            return self.fixes.refuse(InputRejected("other_track", f"fix on track {f.track_id[:64]!r}, {where}"))
        return self.fixes.admit(f.stamp, now, values={"position": f.position, "position_stddev": f.position_stddev},
                                ids={"reference_id": f.reference_id, "sensor": f.sensor, "unit_id": f.unit_id},
                                limits={"position": CHAINAGE})


class SupervisionAdmission:
    """The atp_supervision's inputs: ``report(r, now)`` and ``event(e, now)`` return None
    (admitted) or the refusal; ``orientation``: the train's (+1 / -1: v_est runs along it).
    The report stream's time-out is the supervision's ``report_timeout``."""

    def __init__(self, params: dict | None, orientation: int, report_timeout: float):
        p = self.params = admission_params(params)
        self.orientation = 1 if orientation >= 0 else -1
        limits = StreamLimits(float(p["future_tolerance"]), float(report_timeout), PREVIOUS_LRBGS)
        self.reports = StateStream("localization/etcs", limits, MotionGate.from_params(p))
        self.events = StreamAdmission("localization/etcs_events",
                                      StreamLimits(float(p["future_tolerance"]), float(report_timeout), ordered=False))

    def report(self, r: LocationReport, now: float | None) -> InputRejected | None:
        o = self.orientation
        claimed = r.has_position
        values = {"min_safe_front_end": r.min_safe_front_end, "max_safe_front_end": r.max_safe_front_end,
                  "v_est": r.v_est, "v_ura": r.v_ura} if claimed else {}
        motion = Motion.of(r.t, claimed, r.min_safe_front_end, r.max_safe_front_end, o * r.v_est,
                           r.v_ura if claimed else 0.0)
        return self.reports.admit(motion, now, values=values, ids={"nid_lrbg": r.nid_lrbg, "track_id": r.track_id},
                                  sizes={"previous_lrbgs": len(r.previous_lrbgs)},
                                  limits={"min_safe_front_end": CHAINAGE, "max_safe_front_end": CHAINAGE,
                                          "v_est": SPEED, "v_ura": (0.0, SPEED[1])}
                                  if claimed else None)

    def event(self, e: LocationEvent, now: float | None) -> InputRejected | None:
        return self.events.admit(e.t, now, ids={"nid_bg": e.nid_bg})
