"""ATP supervision to an end of authority (EOA) from the ETCS location reports: SUBSET-026
section 3.13 simplified to a constant-deceleration braking model (the functional core of the
``atp_supervision`` node; docs/etcs.md).

Speeds and distances. ``v = |v_est| + v_ura`` [m/s] is the highest speed the train can have;
distances run along the train's orientation (``orientation``: +1 when its front faces
increasing chainage) from the **max safe front end** to the EOA (``distance_to_eoa`` [m]).
A brake commanded at speed v stops the train within ``v T + a_t T^2 / 2 + (v + a_t T)^2 / (2 a)``
[m] (``braking_distance``: T = ``brake_build_up_time``, the time until the brake acts fully,
during which the train may still accelerate at ``traction_acceleration`` a_t -- the traction
is cut off, the brake builds up: SUBSET-026 3.13.9.3's acceleration over the traction cut-off
--; then the constant deceleration a).

Curves (``curves``), each a distance to the EOA at or below which it is reached:
  * EBI, emergency brake intervention: ``v T + v^2 / (2 emergency_deceleration)``;
  * SBI, service brake intervention: the larger of ``v T + v^2 / (2 service_deceleration)``
    and the EBI distance, so the SBI is never after the EBI (with the defaults, 0.5 < 0.7
    m/s^2, it is the service one and always before; a service deceleration at or above the
    emergency one makes the SBI coincide with the EBI, and the emergency brake wins);
  * warning: ``warning_time * v`` before the SBI; indication: ``indication_time * v``
    before the warning.
``permitted_speed`` is the speed v at which the max safe front end sits exactly on the SBI
curve (the positive root of the quadratic), 0 at and beyond it; it compares with
``|v_est| + v_ura``.

On a network (``end_of_authority_section``) the EOA is a chainage on a section, restated on
the followed path of each report (LocationReport ``path``, core/etcs/network_location.py) as a
path distance, the report's frame; while that path does not reach the section the EOA cannot be
supervised: the service brake, with the reason (``intervention_eoa_off_path``).

Train trip: the **min safe front end** beyond the EOA (status TRIP, emergency brake). A trip
is latched: status TRIP and the emergency brake stay until the train is at a standstill after
a new (changed) end of authority was given (SUBSET-026 leaves Trip mode on the driver's
acknowledgement and a new movement authority; ``set_authority`` stands for both).

Linking reactions (``on_event``): a LocationEvent asking for TRAIN_TRIP trips the train,
SERVICE_BRAKE commands the service brake until standstill, NONE does nothing (counted).

Stale reports. ``check_stale(silence)``: no *admitted* location report (core/etcs/admission.py:
refused and silent alike) for ``report_timeout`` is "position unknown": the emergency brake
(fail safe), whatever speed the last report said -- a report claiming a standstill may be the
last thing an attacker or a failing node sent. The node checks it every 0.1 s on its clock,
from the last admission.

No position. A report without a claimed position (``has_position`` False: initialising or
lost) leaves no end of authority to supervise: the train runs as in Staff Responsible
(SUBSET-026 4.4.11), its speed ``|v_est| + v_ura`` supervised against
``unknown_position_speed`` (V_NVSTFF, 40 km/h by default); above it, or with a speed that
cannot be used (NaN), the emergency brake (fail safe), with the reason. At a standstill the
decision is held as it was (no brake applied, none released) until a report with a position
comes.

Start-up. With ``start_braked`` (default) the supervision starts with the emergency brake,
released at a standstill confirmed as below, with or without a position (a train at the start
of its mission has none yet): a supervision restarted by its launch comes back braking, never
having forgotten a brake or a trip it held.

Holding. A commanded brake is held, whatever the curves say after, until the standstill is
**confirmed**: ``|v_est| < standstill_speed`` in every admitted report with a position for at
least ``standstill_confirmation`` [s] since the brake was commanded (v_ura is left out: a
train at rest may keep a speed uncertainty above standstill_speed and would never be released); one report, or a run of
them shorter than that, releases nothing (SUBSET-026 3.13: an intervention is revoked at the
standstill, never by one report). The emergency brake likewise (always until standstill), a
trip until its release above (also at a confirmed standstill). At a standstill the curves are
evaluated afresh: a train stopped within the SBI distance of its EOA keeps its brake.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum

from ..sensors.base import Param, check_declared, resolve_params
from .records import LocationEvent, LocationReport, Reaction

CHAINAGE_LIMITS = (-1.0e8, 1.0e8)   # [m] an end of authority's chainage


class Status(IntEnum):
    """Supervision status (AtpCommand.STATUS_*)."""
    NORMAL = 0
    INDICATION = 1
    WARNING = 2
    INTERVENTION = 3
    TRIP = 4


class Brake(IntEnum):
    """Commanded brake (AtpCommand.BRAKE_*)."""
    NONE = 0
    SERVICE = 1
    EMERGENCY = 2


PARAMS = {
    "end_of_authority": Param(math.nan, "end of authority, a chainage [m]; NaN = none until one comes on "
                                        "atp/end_of_authority (nothing supervised)", CHAINAGE_LIMITS),
    "end_of_authority_section": Param("", "on a network: the section the end of authority lies on, "
                                          "end_of_authority its chainage there, restated on the followed path of "
                                          "each location report; \"\" on a single line"),
    "orientation": Param(1, "the direction the train's front faces: +1 increasing chainage, -1 decreasing",
                         (-1, 1)),
    "emergency_deceleration": Param(0.7, "emergency brake deceleration of the braking model [m/s^2]",
                                    (0.01, 10.0)),
    "service_deceleration": Param(0.5, "service brake deceleration of the braking model [m/s^2]", (0.01, 10.0)),
    "brake_build_up_time": Param(1.5, "time from the brake command until the brake acts fully, run at the "
                                      "speed of the command [s]", (0.0, 30.0)),
    "traction_acceleration": Param(0.5, "largest acceleration of the train during the brake build-up time "
                                        "(traction not yet cut off) [m/s^2]", (0.0, 5.0)),
    "warning_time": Param(2.0, "the warning point is this time at the current speed before the SBI [s]",
                          (0.0, 60.0)),
    "indication_time": Param(5.0, "the indication point is this time at the current speed before the "
                                  "warning point [s]", (0.0, 120.0)),
    "unknown_position_speed": Param(40.0 / 3.6, "speed supervised while the location report claims no position "
                                                "(Staff Responsible, V_NVSTFF) [m/s]; above it the emergency brake",
                                    (0.0, 100.0)),
    "report_timeout": Param(1.0, "location reports older than this while the train last moved: emergency brake "
                                 "(fail safe) [s]", (0.05, 60.0)),
    "standstill_speed": Param(0.1, "below this |v_est| a commanded brake is released (standstill) [m/s]",
                              (0.001, 5.0)),
    "start_braked": Param(True, "start (and restart) with the emergency brake, released at a standstill confirmed "
                                "over standstill_confirmation, with or without a position: a supervision that "
                                "restarts forgets no brake or trip it held"),
    "standstill_confirmation": Param(1.0, "a brake or trip is released only after every admitted report with a "
                                          "position showed the standstill for this long [s]", (0.0, 60.0)),
}
check_declared(PARAMS, "atp_supervision")


def supervision_params(overrides: dict | None = None) -> dict:
    """PARAMS at their defaults updated by ``overrides`` (ValueError in one line)."""
    return resolve_params(PARAMS, overrides)


def braking_distance(v: float, deceleration: float, build_up_time: float, acceleration: float = 0.0) -> float:
    """Distance [m] from a brake command at speed ``v`` >= 0 [m/s] to the standstill: the
    build-up time [s] accelerating at ``acceleration`` [m/s^2] at most, then ``deceleration``
    [m/s^2] from the speed reached."""
    top = v + acceleration * build_up_time
    return v * build_up_time + 0.5 * acceleration * build_up_time ** 2 + top * top / (2.0 * deceleration)


def stopping_point(front: float, v: float, deceleration: float, build_up_time: float,
                   orientation: int = 1, acceleration: float = 0.0) -> float:
    """Chainage [m] where a front at ``front`` [m] moving at ``v`` [m/s] (either sign: its
    size is used) stops when braked now (``braking_distance`` ahead along ``orientation``)."""
    return front + orientation * braking_distance(abs(v), deceleration, build_up_time, acceleration)


@dataclass(frozen=True)
class Curves:
    """Distances [m] from the max safe front end to the EOA at or below which each point is
    reached at speed ``v`` [m/s]: ebi <= sbi <= warning <= indication."""
    v: float
    ebi: float
    sbi: float
    warning: float
    indication: float


def curves(v: float, params: dict) -> Curves:
    """The supervision curves at speed ``v`` >= 0 [m/s] (module doc) for resolved ``params``."""
    t_bs, a_t = params["brake_build_up_time"], params["traction_acceleration"]
    ebi = braking_distance(v, params["emergency_deceleration"], t_bs, a_t)
    sbi = max(braking_distance(v, params["service_deceleration"], t_bs, a_t), ebi)
    warning = sbi + params["warning_time"] * v
    return Curves(v, ebi, sbi, warning, warning + params["indication_time"] * v)


def permitted_speed(distance: float, params: dict) -> float:
    """Speed [m/s] whose SBI distance is ``distance`` [m] (to the EOA): the root v >= 0 of
    ``braking_distance(v, a, T, a_t) = distance`` with a the smaller deceleration (with
    w = v + a_t T: w^2 / (2 a) + w T - a_t T^2 / 2 = distance); 0 where even v = 0 needs more
    (and for distance <= 0), NaN for NaN."""
    if math.isnan(distance):
        return math.nan
    if distance <= 0.0:
        return 0.0
    a = min(params["service_deceleration"], params["emergency_deceleration"])
    t_bs, a_t = params["brake_build_up_time"], params["traction_acceleration"]
    w = a * (math.sqrt(t_bs * t_bs + 2.0 * (distance + 0.5 * a_t * t_bs * t_bs) / a) - t_bs)
    return max(0.0, w - a_t * t_bs)


START_REASON = "start-up: emergency brake until a confirmed standstill"


class StandstillClock:
    """Confirms a standstill: ``update(t, at_rest, fresh)`` is True once every new report
    (``fresh``; an event or an authority moves nothing) has been ``at_rest`` for ``confirmation``
    [s] without a break; ``break_off()`` starts it afresh (a stale stream)."""

    def __init__(self, confirmation: float):
        self.confirmation = confirmation
        self.since: float | None = None     # the first report of the current run at rest [s]
        self.last = -math.inf               # the last report's time [s]

    def update(self, t: float, at_rest: bool, fresh: bool) -> bool:
        if fresh:
            self.last = t
            if not at_rest:
                self.since = None
            elif self.since is None:
                self.since = t
        return self.since is not None and self.last - self.since >= self.confirmation

    def break_off(self) -> None:
        self.since = None


@dataclass(frozen=True)
class AtpDecision:
    """What the supervision commands (AtpCommand): at ``t`` [s], the status, the brake (held
    until standstill), the end of authority [m] (NaN: none), the distance to it from the max
    safe front end along the orientation [m] and the permitted speed [m/s] (NaN without a
    position or an EOA), and the reason in one line."""
    t: float
    status: Status
    brake: Brake
    end_of_authority: float
    distance_to_eoa: float
    permitted_speed: float
    reason: str


class Supervision:
    """See the module doc. ``update(report)``, ``on_event(event)`` and ``set_authority(eoa)``
    each return the AtpDecision now; ``stats`` counts reports, events, interventions by
    kind (``intervention_<kind>``: ebi, sbi, link, no_position) and trips (``trip_<kind>``:
    eoa, link), each on its onset."""

    def __init__(self, overrides: dict | None = None):
        self.params = p = supervision_params(overrides)
        if p["orientation"] not in (1, -1):
            raise ValueError(f"parameter 'orientation' must be +1 or -1, not {p['orientation']}")
        self.orientation = int(p["orientation"])
        self.end_of_authority = float(p["end_of_authority"])
        self.eoa_section = str(p["end_of_authority_section"])   # "" on a single line
        self.brake = Brake.NONE          # the brake held
        self.brake_reason = ""
        self.trip_reason = ""            # "" unless tripped (latched)
        self._new_authority = False      # a changed EOA since the trip
        self._standstill = StandstillClock(p["standstill_confirmation"])   # reports with a position
        self._start_standstill = StandstillClock(p["standstill_confirmation"])   # any report (start-up)
        self.last_report: LocationReport | None = None
        self.last: AtpDecision | None = None
        self.stats = {"reports": 0, "events": 0, "events_without_reaction": 0, "authorities": 0,
                      "interventions": 0, "intervention_ebi": 0, "intervention_sbi": 0, "intervention_link": 0,
                      "intervention_no_position": 0, "intervention_stale": 0, "intervention_eoa_off_path": 0,
                      "trips": 0, "trip_eoa": 0, "trip_link": 0, "releases": 0, "trips_released": 0}
        if p["start_braked"]:
            self.brake, self.brake_reason = Brake.EMERGENCY, START_REASON

    # ------------------------------------------------------------------ inputs
    def update(self, report: LocationReport) -> AtpDecision:
        """The decision for a new location report."""
        self.stats["reports"] += 1
        self.last_report = report
        return self._decide(report.t, report, fresh=True)

    def on_event(self, event: LocationEvent) -> AtpDecision:
        """Apply a linking event's reaction; the decision with the latest report."""
        self.stats["events"] += 1
        what = f"{event.kind.name.lower()} {event.nid_bg}".strip()
        if event.reaction == Reaction.TRAIN_TRIP:
            self._trip(f"link reaction train trip ({what}: {event.detail})", "link")
        elif event.reaction == Reaction.SERVICE_BRAKE:
            self._intervene(Brake.SERVICE, f"link reaction service brake ({what}: {event.detail})", "link")
        else:
            self.stats["events_without_reaction"] += 1
        return self._decide(event.t, self.last_report)

    def check_stale(self, silence: float) -> AtpDecision | None:
        """``silence`` [s]: time since the last location report came (the node's clock). The
        emergency brake (fail safe) when it exceeds ``report_timeout`` and the last report did
        not show the train at a standstill with a position; the decision (stamped the last
        report's time + silence), else None (nothing changes)."""
        report = self.last_report
        if report is None or not silence > self.params["report_timeout"]:
            return None
        self._standstill.break_off()
        self._start_standstill.break_off()
        if self.brake == Brake.EMERGENCY:
            return None
        reason = (f"no admitted location report for {silence:.2f} s (last at {report.t:.2f} s): position "
                  "unknown, emergency brake (fail safe)")
        self._intervene(Brake.EMERGENCY, reason, "stale")
        self.last = AtpDecision(report.t + silence, Status.INTERVENTION, self.brake, self.end_of_authority, math.nan, math.nan,
                                reason)
        return self.last

    def set_authority(self, end_of_authority: float, section: str | None = None) -> AtpDecision:
        """A new end of authority (chainage [m], finite; ValueError otherwise), on a network on
        ``section`` (None: the section of the last one); the decision with the latest report (t
        NaN before the first)."""
        eoa = float(end_of_authority)
        if not (math.isfinite(eoa) and CHAINAGE_LIMITS[0] <= eoa <= CHAINAGE_LIMITS[1]):
            raise ValueError(f"end of authority {eoa!r} is not a chainage in "
                             f"{CHAINAGE_LIMITS[0]:g} .. {CHAINAGE_LIMITS[1]:g} m")
        self.stats["authorities"] += 1
        section = self.eoa_section if section is None else str(section)
        if (eoa, section) != (self.end_of_authority, self.eoa_section) and self.trip_reason:
            self._new_authority = True
        self.end_of_authority, self.eoa_section = eoa, section
        report = self.last_report
        return self._decide(report.t if report is not None else math.nan, report)

    # ------------------------------------------------------------------ decision
    def _intervene(self, brake: Brake, reason: str, kind: str) -> None:
        """Command ``brake`` (held until standstill); counted when it raises the brake held."""
        if brake > self.brake:
            self.stats["interventions"] += 1
            self.stats[f"intervention_{kind}"] += 1
            self._standstill.break_off()            # the standstill is confirmed from the brake on
        if brake >= self.brake:
            self.brake, self.brake_reason = brake, reason

    def _trip(self, reason: str, kind: str) -> None:
        if not self.trip_reason:
            self.stats["trips"] += 1
            self.stats[f"trip_{kind}"] += 1
            self.trip_reason = reason
            self._new_authority = False
            self._standstill.break_off()
        self.brake, self.brake_reason = Brake.EMERGENCY, reason

    def _decide(self, t: float, report: LocationReport | None, fresh: bool = False) -> AtpDecision:
        """The decision at ``t`` [s] with the latest ``report``; ``fresh``: ``report`` is new (only
        a new report moves the standstill's confirmation, not an event or an authority)."""
        p, eoa = self.params, self.end_of_authority
        speed = abs(report.v_est) if report is not None else math.nan
        usable = (report is not None and report.has_position and math.isfinite(report.v_est)
                  and math.isfinite(report.v_ura) and report.v_ura >= 0.0)
        standstill = speed < p["standstill_speed"]          # False for NaN: moving
        status, distance, allowed = Status.NORMAL, math.nan, math.nan
        confirmed = self._standstill.update(t, usable and standstill, fresh)
        at_start = self._start_standstill.update(t, report is not None and standstill, fresh)
        if self.brake_reason == START_REASON and at_start:
            self.brake, self.brake_reason = Brake.NONE, ""
        if usable:
            if confirmed:                                   # releases first: the curves decide afresh
                if self.trip_reason and self._new_authority:
                    self.trip_reason, self._new_authority = "", False
                    self.stats["trips_released"] += 1
                if self.brake != Brake.NONE and not self.trip_reason:
                    self.brake, self.brake_reason = Brake.NONE, ""
                    self.stats["releases"] += 1
            reason, status, distance, allowed = self._supervise(report)
        elif report is None:
            reason = "no location report yet"
        elif standstill:
            reason = f"no usable position at a standstill (mode {report.mode}): decision held"
            if self.last is not None:
                status = self.last.status
        elif abs(report.v_est) + report.v_ura <= p["unknown_position_speed"]:   # False for NaN
            reason = (f"no usable position (mode {report.mode}): staff responsible, {abs(report.v_est):.2f} + "
                      f"{report.v_ura:.2f} m/s within {p['unknown_position_speed']:.2f} m/s")
            allowed = p["unknown_position_speed"]
        else:
            reason = (f"no usable position while moving (mode {report.mode}, v_est {report.v_est:.2f} + "
                      f"{report.v_ura:.2f} m/s above {p['unknown_position_speed']:.2f} m/s): emergency brake "
                      "(fail safe)")
            self._intervene(Brake.EMERGENCY, reason, "no_position")
        if self.trip_reason:
            status, reason = Status.TRIP, self.trip_reason
        elif self.brake != Brake.NONE:
            if reason != self.brake_reason:                 # commanded before, not (as much) now
                held = "held: no usable position at a standstill" if standstill and not usable \
                    else "held until a confirmed standstill"
                reason = f"{self.brake_reason}; {held}"
            status = Status.INTERVENTION
        self.last = AtpDecision(t, status, self.brake, eoa, distance, allowed, reason)
        return self.last

    def _supervise(self, report: LocationReport) -> tuple[str, Status, float, float]:
        """(reason, status, distance to the EOA [m], permitted speed [m/s]) of a usable report;
        commands the brakes and the trip it calls for."""
        eoa, o = self.end_of_authority, self.orientation
        if math.isnan(eoa):
            return "no end of authority: nothing supervised", Status.NORMAL, math.nan, math.nan
        if self.eoa_section:
            restated = report.path_distance(self.eoa_section, eoa)
            if restated is None:
                reason = (f"end of authority {eoa:.2f} m on section {self.eoa_section} is not on the followed path "
                          f"({', '.join(p.section for p in report.path) or 'none'}): service brake")
                self._intervene(Brake.SERVICE, reason, "eoa_off_path")
                return reason, Status.INTERVENTION, math.nan, math.nan
            eoa = restated
        distance = o * (eoa - report.max_safe_front_end)
        allowed = permitted_speed(distance, self.params)
        beyond = o * (report.min_safe_front_end - eoa)
        if beyond > 0.0:
            self._trip(f"min safe front end {report.min_safe_front_end:.2f} m is {beyond:.2f} m beyond the "
                       f"end of authority {eoa:.2f} m: train trip", "eoa")
            return self.trip_reason, Status.TRIP, distance, allowed
        v = abs(report.v_est) + report.v_ura
        c = curves(v, self.params)
        where = f"{distance:.1f} m to the end of authority at {v:.2f} m/s"
        if distance <= c.ebi:
            reason = f"EBI: {where} (emergency brake needs {c.ebi:.1f} m)"
            self._intervene(Brake.EMERGENCY, reason, "ebi")
            return reason, Status.INTERVENTION, distance, allowed
        if distance <= c.sbi:
            reason = f"SBI: {where} (service brake needs {c.sbi:.1f} m)"
            self._intervene(Brake.SERVICE, reason, "sbi")
            return reason, Status.INTERVENTION, distance, allowed
        if distance <= c.warning:
            return f"warning: {where} (SBI at {c.sbi:.1f} m)", Status.WARNING, distance, allowed
        if distance <= c.indication:
            return f"indication: {where} (SBI at {c.sbi:.1f} m)", Status.INDICATION, distance, allowed
        return f"normal: {where}", Status.NORMAL, distance, allowed
