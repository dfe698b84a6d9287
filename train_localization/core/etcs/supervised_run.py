"""A train supervised to its end of authority in closed loop (docs/etcs.md): dynamics -> sensors
-> fusion -> ETCS location -> ATP supervision -> speed controller -> dynamics, offline.

``EtcsSupervisor`` is ``core.offline.closed_loop``'s supervisor: at every truth step it gives
the location function (core/etcs/location.py) the fused states and balise fixes made since
the step before, the supervision (core/etcs/supervision.py) its reports and events, and
returns the brake to command, as the etcs_location and atp_supervision nodes do live.
``supervised_stop`` runs a scenario with ``control`` and ``atp`` and scores the stop on the
truth: where the true front came to rest against the end of authority (``margin`` [m], > 0
short of it), the trips and the interventions.

``draw_stop`` / ``run_stop`` / ``stop_summary`` are the randomised stops of ``tools/etcs_stops.py``: the driver
(the PID) never brakes for the end of authority, so the supervision must stop the train,
over drawn speeds, EOA places, braking capability, Q_LOCACC, wheel slides in the braking,
radar faults and missed balise groups.

The supervisor admits what it takes as the nodes do (core/etcs/admission.py, the consumer's
clock being the loop's time): fused states and balise fixes for the location function, reports
and events for the supervision, whose report time-out brakes. With ``attacks`` (``draw_attacks``)
it is also handed what an attacker on the same DDS domain would publish (``Attack``): one
state stamped far ahead at a standstill, a report of a standstill in the middle of a brake, a
fix naming a group kilometres away, a flood of unknown balise ids; silent linked groups are the
reader's own fault. Each is refused and counted, or answered by the safe reaction.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from ..measurements import PositionFix
from .admission import FIX_TOPIC, STATE_TOPIC, LocationAdmission, SupervisionAdmission
from .attacks import Attack, draw_attacks, stator_under_attack
from .location import FusedState, LocationTracker, is_balise_fix
from .records import EventKind, LocationEvent, LocationReport
from .supervision import START_REASON, AtpDecision, Brake, Status, Supervision
from .track_data import EtcsData


class EtcsSupervisor:
    """closed_loop's supervisor: the location function and the supervision on the run so far,
    each behind its admission, with ``attacks`` injected where an attacker would publish."""

    def __init__(self, data: EtcsData, location_params: dict | None, atp_params: dict | None,
                 attacks: tuple[Attack, ...] = ()):
        self.tracker = LocationTracker(data, location_params)
        self.supervision = Supervision(atp_params)
        self.location_inputs = LocationAdmission(atp_params, data.track_id)
        self.atp_inputs = SupervisionAdmission(atp_params, self.supervision.orientation,
                                               self.supervision.params["report_timeout"])
        self.attacks = {a.kind: a for a in attacks}
        self.attacked: dict[str, int] = {}      # kind -> spoofed messages handed in
        self.reports: list[LocationReport] = []
        self.events: list[LocationEvent] = []
        self.decisions: list[AtpDecision] = []
        self._estimates = 0
        self._measurements = 0
        self._brake = Brake.NONE
        self._braking_since: float | None = None   # the first brake after the start-up one [s]

    def __call__(self, t: float, run) -> Brake:
        for m in run.measurements[self._measurements:]:
            if is_balise_fix(m):
                self._fix(m, t)
        self._measurements = len(run.measurements)
        for fix in self._spoofed_fixes(t, run):
            self._fix(fix, t)
        for est in run.estimates[self._estimates:]:
            self._state(FusedState.from_estimate(est), t)
        self._estimates = len(run.estimates)
        spoof = self._spoofed_state(t, run)
        if spoof is not None:
            self._state(spoof, t)
        if self.atp_inputs.reports.admitted:
            stale = self.supervision.check_stale(self.atp_inputs.reports.silence(t))
            if stale is not None:
                self.decisions.append(stale)
                self._brake = stale.brake
        if self._braking_since is None and self._brake != Brake.NONE \
                and self.supervision.brake_reason != START_REASON:
            self._braking_since = t
        return self._brake

    # ------------------------------------------------------------------ the chain, admitted
    def _fix(self, fix: PositionFix, t: float) -> None:
        if self.location_inputs.shed(FIX_TOPIC, t) or self.location_inputs.fix(fix, t) is not None:
            return
        self.tracker.on_fix(fix)

    def _state(self, state: FusedState, t: float) -> None:
        if self.location_inputs.shed(STATE_TOPIC, t) or self.location_inputs.state(state, t) is not None:
            return
        report, events = self.tracker.on_state(state)
        for event in events:
            self.events.append(event)
            if self.atp_inputs.event(event, t) is None:
                self._decide(self.supervision.on_event(event))
        self._report(report, t)
        standstill = self._spoofed_report(report)
        if standstill is not None:
            self._report(standstill, t)

    def _report(self, report: LocationReport, t: float) -> None:
        self.reports.append(report)
        if self.atp_inputs.report(report, t) is None:
            self._decide(self.supervision.update(report))

    def _decide(self, decision: AtpDecision) -> None:
        self.decisions.append(decision)
        self._brake = decision.brake

    # ------------------------------------------------------------------ the attacker
    def _count(self, kind: str, n: int = 1) -> None:
        self.attacked[kind] = self.attacked.get(kind, 0) + n

    def _spoofed_state(self, t: float, run) -> FusedState | None:
        """One state stamped ``ahead`` of the clock at a standstill, at the attack's time."""
        a = self.attacks.get("state_ahead")
        if a is None or self.attacked.get(a.kind) or t < a.t or not run.estimates:
            return None
        self._count(a.kind)
        x = self._train_position(run)
        return FusedState(t + a.ahead, x, x - 1.0, x + 1.0, 0.0, 0.001, 0.999, 1)

    def _train_position(self, run) -> float:
        """Where an attacker who reads the published states places the train [m]: the last claimed
        state's position, before any the line's first group (the train starts just behind it)."""
        est = run.estimates[-1] if run.estimates else None
        if est is not None and est.mode in (1, 2):
            return est.position
        return min(g.reference for g in self.tracker.data.groups.values())

    def _spoofed_report(self, report: LocationReport) -> LocationReport | None:
        """A report of a standstill just after a real one, 0.5 s into the first brake."""
        a = self.attacks.get("standstill_report")
        if a is None or self.attacked.get(a.kind) or self._braking_since is None \
                or report.t < self._braking_since + 0.5 or not report.has_position:
            return None
        self._count(a.kind)
        return replace(report, t=report.t + 1e-4, v_est=0.0, v_ura=0.0)

    def _spoofed_fixes(self, t: float, run) -> list[PositionFix]:
        out = []
        far = self.attacks.get("far_group")
        if far is not None and not self.attacked.get(far.kind) and t >= far.t:
            group = self.tracker.data.groups[far.group]
            position = group.positions[0] + 2.0 if far.consistent else self._train_position(run)
            out.append(PositionFix(t, "eurobalise", "attacker", self.tracker.data.track_id, group.balises[0],
                                   position, 0.5, 0))
            self._count(far.kind)
        flood = self.attacks.get("unknown_flood")
        sent = self.attacked.get("unknown_flood", 0)
        if flood is not None and flood.t <= t and sent < int(flood.rate * flood.duration):
            due = max(0, min(int(flood.rate * flood.duration), int((t - flood.t) * flood.rate)) - sent)
            out += [PositionFix(flood.t + (sent + k) / flood.rate, "eurobalise", "attacker",
                                self.tracker.data.track_id, f"XX{sent + k}", 1000.0, 0.5, 0) for k in range(due)]
            self._count(flood.kind, due)
        return out

    def refused(self) -> dict[str, int]:
        """Refusals of every admitted stream by ``<stream>/<reason>``, and the shed messages."""
        out = {}
        for stream in (self.location_inputs.states.stream, self.location_inputs.fixes, self.atp_inputs.reports.stream,
                       self.atp_inputs.events):
            out.update({f"{stream.name}/{k}": v for k, v in stream.refused.items()})
        out.update({f"shed/{k}": v for k, v in self.location_inputs.shed_counts.items()})
        return out


@dataclass
class StopResult:
    """A supervised run scored on its truth: how close the true front came to the EOA."""
    end_of_authority: float          # chainage [m]
    closest_front: float             # the true front's furthest point along the orientation [m]
    margin: float                    # EOA - closest_front along the orientation [m]: > 0 short of it
    stopped: bool                    # at rest (|v| < 0.05 m/s) at some time after the first intervention
    first_stop_margin: float         # EOA - the true front where it first came to rest after a brake [m]; NaN if never
    trips: int
    interventions: int
    max_status: int
    min_truth_to_safe_front: float   # least (truth - min safe front end) along the orientation [m]: >= 0 safe
    max_safe_front_overshoot: float  # largest (truth - max safe front end) [m]: <= 0 safe
    events: dict = field(default_factory=dict)
    releases_while_moving: int = 0   # brake releases while the true speed was above 0.1 m/s
    refused: dict = field(default_factory=dict)    # <stream>/<reason> -> messages refused or shed
    stator: dict = field(default_factory=dict)     # attacks.stator_under_attack's, with a stator_spoof
    lrbgs: list = field(default_factory=list)      # the groups that became the LRBG, in order
    attacked: dict = field(default_factory=dict)   # attack kind -> spoofed messages handed in
    supervisor: EtcsSupervisor | None = None
    loop: object = None


def supervised_stop(scenario, t_end: float | None = None, attacks: tuple[Attack, ...] = ()) -> StopResult:
    """Run a scenario with ``control`` and ``atp`` in closed loop under the ETCS supervision,
    with ``attacks`` injected."""
    from ..offline import closed_loop
    orientation = scenario.orientation()
    atp = {"orientation": orientation, **scenario.atp}
    data = EtcsData.from_track(scenario.track)
    sup = EtcsSupervisor(data, {"orientation": orientation}, atp, attacks)
    loop = closed_loop(scenario, t_end, supervisor=sup)
    eoa = float(atp["end_of_authority"])
    truth_t = np.array([s.stamp for s in loop.truth])
    truth_x = np.array(loop.distance)
    truth_v = np.array([s.speed for s in loop.truth])
    closest = float(np.max(truth_x * orientation)) * orientation
    started = next((k for k, (_, brake) in enumerate(loop.brakes) if brake == Brake.NONE), len(loop.brakes))
    braked = [t for t, brake in loop.brakes[started:] if brake != Brake.NONE]   # after the start-up brake
    at_rest = np.flatnonzero((truth_t > braked[0]) & (np.abs(truth_v) < 0.05)) if braked else np.array([], int)
    stopped = bool(at_rest.size)
    first_stop = (eoa - float(truth_x[at_rest[0]])) * orientation if stopped else math.nan
    reps = [r for r in sup.reports if r.has_position]
    gap_min, over_max = math.inf, -math.inf
    if reps:
        t = np.array([r.t for r in reps])
        x = np.interp(t, truth_t, truth_x)
        lo = np.array([r.min_safe_front_end for r in reps])
        hi = np.array([r.max_safe_front_end for r in reps])
        gap_min = float(np.min((x - lo) * orientation))
        over_max = float(np.max((x - hi) * orientation))
    kinds: dict[str, int] = {}
    for e in sup.events:
        kinds[e.kind.name.lower()] = kinds.get(e.kind.name.lower(), 0) + 1
    stats = sup.supervision.stats
    brakes = [brake for _, brake in loop.brakes]
    released = sum(1 for k in range(1, len(brakes)) if brakes[k - 1] != Brake.NONE and brakes[k] == Brake.NONE
                   and abs(truth_v[k]) > 0.1)
    return StopResult(eoa, closest, (eoa - closest) * orientation, stopped, first_stop,
                      int(stats.get("trips", 0)), int(stats.get("interventions", 0)),
                      max((int(d.status) for d in sup.decisions), default=int(Status.NORMAL)),
                      gap_min, over_max, kinds, releases_while_moving=released, refused=sup.refused(),
                      attacked=dict(sup.attacked), supervisor=sup, loop=loop,
                      lrbgs=[e.nid_bg for e in sup.events if e.kind == EventKind.LRBG],
                      stator=stator_under_attack(loop, orientation, sup.attacks["stator_spoof"])
                      if "stator_spoof" in sup.attacks else {})


# ----------------------------------------------------------------------------- randomised stops
KMH = 1.0 / 3.6
MASS = 4.0e5            # [kg] the train of the drawn stops (its PID gains follow from it)


def draw_stop(seed: int) -> dict:
    """The scenario dict of randomised stop ``seed``: a 200 m train on a drawn ETCS line (balise
    groups of two every 600-1500 m, Q_LOCACC 1-5 m, linking both ways, reaction none or service
    brake), starting just behind the first group, its driver running at 60-160 km/h towards an
    EOA 2-6 km ahead and never braking for it; the braking it really has (0.55-0.9 m/s^2) is
    at least what the supervision assumes (80-95 % of it); a 5-25 % wheel slide in the braking
    in half the runs, a Doppler scale fault in a third, a silent balise group on the way in a
    third."""
    rng = np.random.default_rng(seed)

    def u(lo, hi):
        return float(f"{rng.uniform(lo, hi):.6g}")
    spacing = u(600.0, 1500.0)
    q = [1.0, 1.0, 2.0, 3.0, 5.0]
    first = 500.0
    v_top = u(60.0, 160.0) * KMH
    eoa_distance = u(2000.0, 6000.0)
    start = first - u(10.0, 60.0)
    eoa = start + eoa_distance
    length = eoa + 3000.0
    groups = np.arange(first, length - 100.0, spacing)
    balises = []
    for n, x in enumerate(groups):
        qa = q[int(rng.integers(0, len(q)))]
        balises += [{"id": f"BG{n:03d}a", "position": float(x), "group": f"BG{n:03d}", "q_locacc": qa},
                    {"id": f"BG{n:03d}b", "position": float(x) + 3.0, "group": f"BG{n:03d}", "q_locacc": qa}]
    reaction = ("none", "service_brake")[int(rng.integers(0, 2))]
    decel = u(0.55, 0.9)
    assumed = decel * u(0.8, 0.95)
    lag = u(0.2, 1.0)
    resistance = (4000.0, 100.0, 6.0)
    t_run = v_top / (decel * 0.8) + eoa_distance / v_top + v_top / decel + 40.0
    sensors = {"wheel_sensor": {}, "doppler_radar": {}, "eurobalise_reader": {},
               "axle_counter": {"heads": "AC00,AC01"}}
    faults = {}
    if rng.random() < 0.5:
        brake_at = (eoa_distance - v_top ** 2 / (2.0 * assumed)) / v_top + v_top / (decel * 0.8)
        ratio = -u(0.05, 0.25)
        sensors["wheel_sensor"]["slip_episodes"] = [u(0.5 * brake_at, 1.2 * brake_at), u(1.0, 6.0), ratio]
        faults["slide"] = ratio
    if rng.random() < 1.0 / 3.0:
        t0 = u(0.0, t_run)
        sensors["doppler_radar"]["faults"] = f"{t0:.5g}-{t0 + u(2.0, 30.0):.5g}:{u(-0.08, 0.08):.4g}"
        faults["doppler"] = sensors["doppler_radar"]["faults"]
    on_the_way = [f"BG{n:03d}" for n, x in enumerate(groups) if start + 50.0 < x < eoa - 50.0]
    if on_the_way and rng.random() < 1.0 / 3.0:
        silent = on_the_way[int(rng.integers(0, len(on_the_way)))]
        sensors["eurobalise_reader"]["silent_balises"] = f"{silent}a,{silent}b"
        faults["silent_group"] = silent
    duration = float(f"{t_run:.6g}")
    track = {"track_id": f"etcs_stop_{seed}", "length": float(f"{length:.6g}"),
             "equipment": {"eurobalise": balises,
                           "axle_counter_head": [{"id": "AC00", "position": first + 0.5 * spacing},
                                                 {"id": "AC01", "position": first + 1.5 * spacing}]},
             "etcs": {"linking": "auto", "link_reaction": reaction}}
    omega, zeta = 0.3, 0.9
    return {"name": f"etcs_stop_{seed}", "seed": int(seed), "track": track, "duration": duration, "truth_rate": 100.0,
            "vehicle": {"type": "conventional", "length": 200.0, "wheel_diameter": 0.92,
                        "axles": [2.5, 5.0, 22.5, 25.0, 27.5, 30.0, 47.5, 50.0]},
            "initial": {"position": float(f"{start:.6g}"), "speed": 0.0},
            "control": {"kind": "pid", "kp": 2.0 * zeta * omega * MASS, "ki": omega ** 2 * MASS, "kd": 0.0,
                        "max_speed_stddev": 2.0,
                        "setpoints": [{"t": 1.0, "speed": v_top}, {"t": duration - 15.0, "speed": 0.0}]},
            "dynamics": {"inertia": MASS, "lim_radius": 1.0, "lim_force": decel * MASS + 0.0, "lims": 1,
                         "force_lag": lag, "resistance_a": resistance[0], "resistance_b": resistance[1],
                         "resistance_c": resistance[2], "substep": 0.01},
            "atp": {"end_of_authority": float(f"{eoa:.6g}"), "service_deceleration": assumed,
                    "emergency_deceleration": assumed, "brake_build_up_time": lag + 1.0,
                    "traction_acceleration": decel},
            "sensors": sensors,
            "draw": {"top_speed_kmh": v_top / KMH, "eoa_distance": eoa_distance, "deceleration": decel,
                     "assumed_deceleration": assumed, "force_lag": lag, "link_reaction": reaction,
                     "balise_spacing": spacing, **faults}}


def stop_summary(results: list[dict]) -> dict:
    """Figures of randomised stops (``run_stop`` dicts): the closest approach to the EOA over
    the run (``margin_m``, goal: never negative; the driver drives on after each release), where
    the train first came to rest after a brake (``first_stop_margin_m``), trips (goal 0), runs
    that did not stop, and the safe front ends' coverage."""
    ok = [r for r in results if "error" not in r]
    margins = np.array([r["margin"] for r in ok])
    first = np.array([r["first_stop_margin"] for r in ok if r["stopped"]])
    return {"runs": len(results), "errors": [[r["seed"], r["error"]] for r in results if "error" in r],
            "margin_m": ({"min": float(margins.min()), "p5": float(np.percentile(margins, 5)),
                          "median": float(np.median(margins)), "max": float(margins.max())} if margins.size else None),
            "first_stop_margin_m": ({"min": float(first.min()), "median": float(np.median(first)),
                                     "p95": float(np.percentile(first, 95)), "max": float(first.max())}
                                    if first.size else None),
            "overruns": sum(1 for r in ok if r["margin"] < 0.0),
            "trips": sum(r["trips"] for r in ok), "not_stopped": [r["seed"] for r in ok if not r["stopped"]],
            "safe_front_violations": sum(1 for r in ok if r["min_truth_to_safe_front"] < 0.0
                                         or r["max_safe_front_overshoot"] > 0.0),
            "interventions": sum(r["interventions"] for r in ok),
            "missed_linked_groups": sum(r["events"].get("missed_linked_group", 0) for r in ok),
            "releases_while_moving": sum(r["releases_while_moving"] for r in ok),
            "far_groups_taken": sum(1 for r in ok for a in r.get("attacks", ()) if a["kind"] == "far_group"
                                    and a["group"] in r["lrbgs"]),
            "attacks": _tally(r["attacked"] for r in ok),
            "refused": _tally(r["refused"] for r in ok),
            "stator": _stator_summary([r["stator"] for r in ok if r.get("stator")])}


def _stator_summary(runs: list[dict]) -> dict | None:
    """The stator attacks: runs, sections switched off under the vehicle and the thrust lost [s]
    with the attack and without it, what was refused."""
    if not runs:
        return None
    return {"runs": len(runs),
            "switched_off_under_vehicle": {k: sum(r[k]["switched_off_under_vehicle"] for r in runs)
                                           for k in ("clean", "attacked")},
            "thrust_loss_s": {k: sum(r[k]["thrust_loss_s"] for r in runs) for k in ("clean", "attacked")},
            "max_extra_thrust_loss_s": max(r["attacked"]["thrust_loss_s"] - r["clean"]["thrust_loss_s"] for r in runs),
            "refused": _tally(r["attacked"]["refused"] for r in runs)}


def _tally(dicts) -> dict:
    total: dict = {}
    for d in dicts:
        for k, v in d.items():
            total[k] = total.get(k, 0) + v
    return dict(sorted(total.items()))


def run_stop(seed: int, attacks: bool = False) -> dict:
    """Draw, run and score randomised stop ``seed`` (with drawn ``attacks``): a JSON-serialisable
    dict (an error entry if the run fails)."""
    import traceback
    from ..scenario import Scenario
    data = draw_stop(seed)
    drawn = draw_attacks(seed, data) if attacks else ()
    out = {"seed": int(seed), "draw": data["draw"], "attacks": [a.__dict__ for a in drawn]}
    try:
        res = supervised_stop(Scenario.from_dict({k: v for k, v in data.items() if k != "draw"}), attacks=drawn)
    except Exception as exc:     # a failing run is a result, not the end of the others
        return {**out, "error": f"{type(exc).__name__}: {exc}", "traceback": traceback.format_exc()}
    out.update({k: v for k, v in res.__dict__.items() if k not in ("supervisor", "loop")})
    return out
