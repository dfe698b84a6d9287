"""ATP supervision to an end of authority (core/etcs/supervision.py): the curves' numbers and
order, the trip, the linking reactions, the fail-safe without a position, holding until
standstill, a simulated approach; the speed controller obeying the brake; the node over DDS."""
from __future__ import annotations

import math

import pytest

from conftest import ROOT, spin_until
from train_localization.core.control import SpeedController, control_config
from train_localization.core.offline import closed_loop
from train_localization.core.etcs import supervision as atp
from train_localization.core.etcs.records import EventKind, LocationEvent, LocationReport, QDirLrbg, Reaction
from train_localization.core.etcs.supervision import Brake, Status, Supervision

EOA = 5000.0


def _report(t: float, front: float, v: float, half: float = 2.0, v_ura: float = 0.5, mode: int = 1,
            orientation: int = 1) -> LocationReport:
    """A report of the estimated front end ``front`` with a fixed interval +- ``half`` [m]."""
    return LocationReport(t, "test", "BG1", 0.0, QDirLrbg.NOMINAL, 1.0, half, half, front,
                          front - orientation * half, front + orientation * half, v, v_ura, False, (), mode)


def _sup(**overrides) -> Supervision:
    """A supervision to EOA; the train of these tests does not accelerate during the brake
    build-up (traction_acceleration 0) unless told."""
    return Supervision({"end_of_authority": EOA, "traction_acceleration": 0.0, "start_braked": False, **overrides})


def _diag_values(msgs, name_part):
    """Key/values of the latest status of a node."""
    values = {}
    for arr in msgs:
        for st in arr.status:
            if name_part in st.name:
                values = {kv.key: kv.value for kv in st.values}
    return values


def test_the_enums_are_the_messages_constants_and_every_parameter_has_a_range():
    from train_localization_msgs.msg import AtpCommand, EtcsEvent
    assert {s.name: int(s) for s in Status} == {n[7:]: getattr(AtpCommand, n) for n in dir(AtpCommand)
                                                 if n.startswith("STATUS_")}
    assert {b.name: int(b) for b in Brake} == {n[6:]: getattr(AtpCommand, n) for n in dir(AtpCommand)
                                                if n.startswith("BRAKE_")}
    assert {r.name: int(r) for r in Reaction} == {n[9:]: getattr(EtcsEvent, n) for n in dir(EtcsEvent)
                                                   if n.startswith("REACTION_")}
    assert all(p.limits for p in atp.PARAMS.values() if p.numeric)
    with pytest.raises(ValueError, match="orientation"):
        Supervision({"orientation": 0})
    with pytest.raises(ValueError, match="service_deceleration"):
        Supervision({"service_deceleration": 0.0})


def test_the_curves_are_the_constant_deceleration_formulas():
    p = atp.supervision_params({"traction_acceleration": 0.0})
    v = 20.0 + 0.5                                       # |v_est| + v_ura
    c = atp.curves(v, p)
    assert c.ebi == pytest.approx(20.5 * 1.5 + 20.5 ** 2 / (2 * 0.7), abs=1e-12)   # 330.93 m
    assert c.sbi == pytest.approx(20.5 * 1.5 + 20.5 ** 2 / (2 * 0.5), abs=1e-12)   # 451.00 m
    assert c.warning == pytest.approx(c.sbi + 2.0 * 20.5, abs=1e-12)
    assert c.indication == pytest.approx(c.warning + 5.0 * 20.5, abs=1e-12)
    assert atp.permitted_speed(c.sbi, p) == pytest.approx(20.5, abs=1e-9)
    assert atp.permitted_speed(-1.0, p) == 0.0 and math.isnan(atp.permitted_speed(math.nan, p))
    assert atp.stopping_point(100.0, -20.5, 0.7, 1.5, orientation=-1) == pytest.approx(100.0 - c.ebi)
    # a service deceleration above the emergency one: the SBI coincides with the EBI, never after it
    fast = atp.supervision_params({"service_deceleration": 1.0, "traction_acceleration": 0.0})
    assert atp.curves(v, fast).sbi == atp.curves(v, fast).ebi

    # the supervision on either side of the EBI distance, in both orientations
    for o in (1, -1):
        eoa = o * EOA
        for margin, brake in ((-0.01, Brake.EMERGENCY), (0.01, Brake.SERVICE)):
            sup = Supervision({"end_of_authority": eoa, "orientation": o, "traction_acceleration": 0.0,
                              "start_braked": False})
            d = sup.update(_report(1.0, eoa - o * (c.ebi + margin + 2.0), o * 20.0, orientation=o))
            assert (d.status, d.brake) == (Status.INTERVENTION, brake), d
            assert d.distance_to_eoa == pytest.approx(c.ebi + margin)
            assert d.permitted_speed == pytest.approx(atp.permitted_speed(c.ebi + margin, p))


def _approach(sup: Supervision, v: float, start: float, dt: float = 0.05):
    """(front, decision) of a train approaching the EOA at constant speed (the brake ignored)."""
    out, front, t = [], start, 0.0
    while front < EOA + 10.0:
        out.append((front, sup.update(_report(t, front, v))))
        t, front = t + dt, front + v * dt
    return out


def test_indication_warning_sbi_ebi_and_trip_come_in_this_order_along_the_approach():
    sup = _sup()
    run = _approach(sup, 20.0, 3000.0)
    first = {}
    for front, d in run:
        key = d.brake.name if d.status == Status.INTERVENTION else d.status.name
        first.setdefault(key, front)
    order = ["NORMAL", "INDICATION", "WARNING", "SERVICE", "EMERGENCY", "TRIP"]
    assert list(first) == order, first
    assert [first[k] for k in order] == sorted(first[k] for k in order)
    c = atp.curves(20.5, sup.params)
    assert first["SERVICE"] == pytest.approx(EOA - 2.0 - c.sbi, abs=1.0 + 1e-6)   # 1 m: a step of 0.05 s
    trip = next(front for front, d in run if d.status == Status.TRIP)
    assert trip - 2.0 > EOA and trip - 2.0 - 1.0 <= EOA        # the min safe front end passes the EOA
    assert sup.stats["intervention_sbi"] == sup.stats["intervention_ebi"] == 1
    assert sup.stats["trips"] == sup.stats["trip_eoa"] == 1 and sup.stats["interventions"] == 2


def test_a_trip_is_latched_until_a_standstill_after_a_new_authority():
    sup = _sup()
    d = sup.update(_report(1.0, EOA + 2.5, 5.0))              # min safe front end 0.5 m beyond
    assert (d.status, d.brake) == (Status.TRIP, Brake.EMERGENCY) and "beyond" in d.reason
    d = sup.update(_report(2.0, EOA + 4.0, 0.0))              # stopped: still tripped, same authority
    assert (d.status, d.brake) == (Status.TRIP, Brake.EMERGENCY)
    assert sup.set_authority(EOA + 500.0).status == Status.TRIP   # one report at rest: no confirmed standstill
    sup = _sup()
    sup.update(_report(1.0, EOA + 2.5, 5.0))
    sup.update(_report(2.0, EOA + 4.0, 0.0))
    d = sup.update(_report(3.0, EOA + 4.0, 0.0))              # standstill confirmed (1 s): still tripped
    assert (d.status, d.brake) == (Status.TRIP, Brake.EMERGENCY)
    assert sup.set_authority(EOA).status == Status.TRIP       # the same authority again is no new one
    d = sup.set_authority(EOA + 500.0)                        # at a confirmed standstill: released
    assert (d.status, d.brake) == (Status.NORMAL, Brake.NONE), d
    assert sup.stats["trips"] == 1 and sup.stats["trips_released"] == 1
    with pytest.raises(ValueError, match="end of authority"):
        sup.set_authority(math.nan)


def test_linking_reactions_trip_brake_or_are_only_counted():
    sup = _sup()
    sup.update(_report(1.0, 1000.0, 20.0))
    d = sup.on_event(LocationEvent(1.1, EventKind.MISSED_LINKED_GROUP, "BG7", Reaction.NONE, "window closed"))
    assert (d.status, d.brake) == (Status.NORMAL, Brake.NONE)
    assert sup.stats["events_without_reaction"] == 1
    d = sup.on_event(LocationEvent(1.2, EventKind.OUTSIDE_WINDOW, "BG8", Reaction.SERVICE_BRAKE, "read 30 m early"))
    assert (d.status, d.brake) == (Status.INTERVENTION, Brake.SERVICE) and "BG8" in d.reason
    d = sup.update(_report(2.0, 1020.0, 19.0))                 # far from the EOA: held until standstill
    assert (d.status, d.brake) == (Status.INTERVENTION, Brake.SERVICE) and "held until a confirmed standstill" in d.reason
    d = sup.update(_report(29.0, 1200.0, 0.05))
    assert d.brake == Brake.SERVICE and "confirmed standstill" in d.reason   # one report at rest releases nothing
    d = sup.update(_report(30.0, 1200.0, 0.05))
    assert (d.status, d.brake) == (Status.NORMAL, Brake.NONE)
    sup.update(_report(40.0, 1300.0, 15.0))
    d = sup.on_event(LocationEvent(40.1, EventKind.WRONG_DIRECTION, "BG9", Reaction.TRAIN_TRIP, "against linking"))
    assert (d.status, d.brake) == (Status.TRIP, Brake.EMERGENCY) and "BG9" in d.reason
    assert sup.stats["intervention_link"] == 1 and sup.stats["trip_link"] == 1 and sup.stats["events"] == 3


def test_no_position_is_staff_responsible_above_its_speed_an_emergency_brake_and_at_a_standstill_holds():
    sup = _sup()
    d = sup.update(_report(1.0, 1000.0, 0.0, mode=0))          # initialising at rest: nothing to do
    assert (d.status, d.brake) == (Status.NORMAL, Brake.NONE) and "standstill" in d.reason
    d = sup.update(_report(1.5, math.nan, 8.0, mode=0))        # no position yet, within 40 km/h: staff responsible
    assert (d.status, d.brake) == (Status.NORMAL, Brake.NONE) and "staff responsible" in d.reason
    assert d.permitted_speed == pytest.approx(40.0 / 3.6)
    d = sup.update(_report(2.0, math.nan, 13.0, mode=3))       # lost while moving above it: fail safe
    assert (d.status, d.brake) == (Status.INTERVENTION, Brake.EMERGENCY) and "fail safe" in d.reason
    assert math.isnan(d.distance_to_eoa)
    d = sup.update(_report(9.0, math.nan, 0.0, mode=3))        # stopped, still lost: the brake is held
    assert d.brake == Brake.EMERGENCY and "no usable position at a standstill" in d.reason
    assert sup.update(_report(10.0, 1010.0, 0.0)).brake == Brake.EMERGENCY   # a position again, at rest
    d = sup.update(_report(11.0, 1010.0, 0.0))                 # ... for 1 s: released
    assert (d.status, d.brake) == (Status.NORMAL, Brake.NONE)
    d = sup.update(_report(12.0, 1010.0, math.nan))            # a claimed position without a speed
    assert d.brake == Brake.EMERGENCY
    assert sup.stats["intervention_no_position"] == 2 and sup.stats["releases"] == 1


def test_a_brake_is_held_until_standstill_whatever_the_curves_say_after():
    sup = _sup()
    d = sup.update(_report(1.0, EOA - 2.0 - 400.0, 20.0))      # 400 m at 20.5 m/s: SBI (451 m)
    assert d.brake == Brake.SERVICE
    d = sup.set_authority(EOA + 5000.0)                        # a longer authority: nothing needs braking
    assert (d.status, d.brake) == (Status.INTERVENTION, Brake.SERVICE) and "held" in d.reason
    d = sup.update(_report(2.0, EOA - 380.0, 0.2))             # slow, not yet at rest (0.1 m/s)
    assert d.brake == Brake.SERVICE
    assert sup.update(_report(3.0, EOA - 380.0, -0.09)).brake == Brake.SERVICE
    d = sup.update(_report(4.0, EOA - 380.0, -0.09))
    assert (d.status, d.brake) == (Status.NORMAL, Brake.NONE)
    sup = _sup()
    assert sup.update(_report(1.0, EOA - 2.0 - 300.0, 20.0)).brake == Brake.EMERGENCY   # EBI (331 m)
    assert sup.update(_report(2.0, EOA - 2.0 - 290.0, 20.0)).brake == Brake.EMERGENCY
    sup.set_authority(EOA + 5000.0)
    assert sup.update(_report(3.0, EOA - 280.0, 1.0)).brake == Brake.EMERGENCY
    assert sup.update(_report(5.0, EOA - 279.0, 0.0)).brake == Brake.EMERGENCY
    assert sup.update(_report(6.0, EOA - 279.0, 0.0)).brake == Brake.NONE
    # stopped within the SBI distance of the EOA (at v = v_ura): the service brake stays
    sup = _sup()
    d = sup.update(_report(1.0, EOA - 2.97, 0.0))                # 0.97 m: between EBI 0.93, SBI 1.0 m
    assert (d.status, d.brake) == (Status.INTERVENTION, Brake.SERVICE)


def test_the_curves_allow_for_the_acceleration_during_the_brake_build_up():
    """A train still accelerating at 0.5 m/s^2 while its brake builds up over 1.5 s: 20.5 m/s
    becomes 21.25 m/s; the EBI distance is the build-up distance then the braking from there,
    and the permitted speed inverts it. At rest the train still needs a_t T^2 / 2 + (a_t T)^2 /
    (2 a): a brake released at a standstill just short of the EOA is commanded again."""
    p = atp.supervision_params()
    assert p["traction_acceleration"] == 0.5
    c = atp.curves(20.5, p)
    assert c.ebi == pytest.approx(20.5 * 1.5 + 0.25 * 1.5 ** 2 + 21.25 ** 2 / 1.4, abs=1e-12)
    assert c.sbi == pytest.approx(20.5 * 1.5 + 0.25 * 1.5 ** 2 + 21.25 ** 2 / 1.0, abs=1e-12)
    assert atp.permitted_speed(c.sbi, p) == pytest.approx(20.5, abs=1e-9)
    at_rest = atp.curves(0.0, p).sbi
    assert at_rest == pytest.approx(0.25 * 1.5 ** 2 + 0.75 ** 2 / 1.0)
    assert atp.permitted_speed(0.5 * at_rest, p) == 0.0
    sup = Supervision({"end_of_authority": EOA, "start_braked": False})
    between = 0.5 * (atp.curves(0.0, p).ebi + at_rest)
    assert sup.update(_report(1.0, EOA - 2.0 - between, 0.0, v_ura=0.0)).brake == Brake.SERVICE


def test_a_train_braking_when_commanded_stops_short_of_the_eoa_and_never_trips():
    """A train at 30 m/s, location reports every 0.1 s with an interval of +- 2 m around an
    estimate 1.5 m off the truth and a speed 1 % high (v_ura 0.5 m/s); the brake acts fully
    brake_build_up_time after the command, then at the service deceleration."""
    sup = _sup()
    p = sup.params
    dt, x, v, t = 0.1, 0.0, 30.0, 0.0
    commanded_at, decisions = None, []
    while t < 200.0 and not (v == 0.0 and decisions[-1].brake == Brake.NONE):
        d = sup.update(_report(t, x + 1.5, 1.01 * v))
        decisions.append(d)
        assert d.status != Status.TRIP and d.brake != Brake.EMERGENCY, d
        if d.brake != Brake.NONE and commanded_at is None:
            commanded_at = t
        a = -p["service_deceleration"] if commanded_at is not None and t - commanded_at >= \
            p["brake_build_up_time"] - 1e-9 else 0.0
        step = min(dt, v / -a) if a < 0.0 else dt
        x, v, t = x + v * step + 0.5 * a * step * step, max(0.0, v + a * step), t + dt
        assert x + 3.5 < EOA                                    # the max safe front end too
    assert v == 0.0 and 0.0 < EOA - x < 60.0, (x, v)            # stopped short, not far short
    statuses = [d.status for d in decisions]
    assert Status.INDICATION in statuses and Status.WARNING in statuses
    assert statuses.index(Status.INDICATION) < statuses.index(Status.WARNING) < statuses.index(Status.INTERVENTION)
    assert sup.stats["intervention_sbi"] == 1 and sup.stats["trips"] == 0 and sup.stats["releases"] == 1
    assert decisions[-1].brake == Brake.NONE


def test_the_speed_controller_brakes_fully_while_commanded_and_then_resumes_its_pid():
    """Under an ATP brake: no thrust and the friction brake's full demand, whatever the fused
    state says (an unusable speed too); released, the PID from its set-point."""
    params, sps = control_config({"setpoints": [{"t": 0.0, "speed": 5.0}]})
    ctrl = SpeedController(params, sps, 1000.0)
    ctrl.update(0.0, 4.0)
    ctrl.update(0.1, 4.0)
    assert ctrl.integral > 0.0 and ctrl.brake_demand == 0.0
    ctrl.set_brake(Brake.SERVICE)
    assert ctrl.brake_demand == 1.0
    assert ctrl.update(0.2, 4.0) == 0.0 and ctrl.integral == 0.0
    assert ctrl.update(0.3, math.nan, speed_stddev=math.nan) == 0.0 and ctrl.brake_demand == 1.0
    ctrl.set_brake(2)
    assert ctrl.update(0.5, 3.0, speed_stddev=50.0) == 0.0 and ctrl.brake_demand == 1.0
    ctrl.set_brake(Brake.NONE)
    assert ctrl.brake_demand == 0.0
    u = ctrl.update(0.6, 3.0)                                   # the PID from its set-point, integral from 0
    assert u == pytest.approx(params["kp"] * 2.0 + params["ki"] * 2.0 * 0.1)
    with pytest.raises(ValueError):
        ctrl.set_brake(3)


def test_the_closed_loop_obeys_a_supervisor_and_is_unchanged_without_a_brake():
    from train_localization.core.scenario import Scenario
    sc = Scenario.from_yaml(ROOT / "config" / "scenario_rig.yaml")
    plain = closed_loop(sc, t_end=8.0)
    idle = closed_loop(sc, t_end=8.0, supervisor=lambda t, run: Brake.NONE)
    assert idle.commands == plain.commands and plain.brakes == [] and len(idle.brakes) == len(idle.commands)
    braked = closed_loop(sc, t_end=8.0, supervisor=lambda t, run: Brake.EMERGENCY if t >= 6.0 else Brake.NONE)
    before = [c for c in braked.commands if c[0] < 6.0]
    assert before == plain.commands[:len(before)]
    after = [(t, f) for t, _, f in braked.commands if t >= 6.0]
    assert after and all(f == 0.0 for _, f in after)             # no thrust, the friction brake
    assert braked.dynamics.brake_command == braked.dynamics.brake_limit > 0.0
    assert braked.distance[-1] < plain.distance[-1]
    speeds = [s.speed for s in braked.truth]
    assert min(speeds) >= 0.0 and speeds[-1] < speeds[600]        # braked, never reversed


def test_a_friction_brake_stops_the_vehicle_and_holds_it_without_reversing_it():
    """core/dynamics.py: the brake opposes the motion, brings the vehicle to rest and holds it
    against a thrust up to static friction + brake; with a brake of 0 the motion is as before."""
    from train_localization.core.dynamics import Dynamics
    from train_localization.core.track import Track
    track = Track.from_dict({"track_id": "t", "length": 10000.0})
    params = {"inertia": 4.0e5, "lim_radius": 1.0, "lim_force": 2.0e5, "lims": 1, "force_lag": 0.0,
              "resistance_a": 4000.0, "resistance_b": 0.0, "resistance_c": 0.0, "substep": 0.01}
    dyn = Dynamics(params, track, 100.0, 10.0)
    dyn.set_brake(1.0)
    for _ in range(3000):
        dyn.step(0.01)
    # 0.5 m/s^2 of brake and 0.01 of friction: at rest after 19.6 s and 98 m, held there
    assert dyn.speed == 0.0 and dyn.distance == pytest.approx(100.0 + 10.0 ** 2 / (2 * 0.51), abs=0.2)
    dyn.set_command(-1.5e5)                                      # pushing back: held by the brake
    for _ in range(100):
        dyn.step(0.01)
    assert dyn.speed == 0.0
    dyn.set_brake(0.0)
    for _ in range(100):
        dyn.step(0.01)
    assert dyn.speed < 0.0                                       # released: the thrust moves it


def _location_msg(t: float, front: float, v: float, lo: float | None = None, mode: int = 1):
    from train_localization_msgs.msg import EtcsLocation
    m = EtcsLocation(track_id="test", nid_lrbg="BG1", d_lrbg=front - 100.0, q_dirlrbg=1, q_locacc=1.0,
                     l_doubtover=2.0, l_doubtunder=2.0, estimated_front_end=front,
                     min_safe_front_end=front - 2.0 if lo is None else lo, max_safe_front_end=front + 2.0,
                     v_est=v, v_ura=0.5, mode=mode)
    m.header.stamp.sec, m.header.stamp.nanosec = int(t), int(round((t % 1) * 1e9))
    return m


def test_the_node_converts_reports_and_refuses_one_it_cannot_use():
    from train_localization.core.signals import InputRejected
    from train_localization.core.convert import etcs_report_from_msg as report_from_msg
    r = report_from_msg(_location_msg(12.5, 500.0, 20.0))
    assert r == LocationReport(12.5, "test", "BG1", 400.0, QDirLrbg.NOMINAL, 1.0, 2.0, 2.0, 500.0, 498.0, 502.0,
                               20.0, 0.5, False, (), 1)
    with pytest.raises(InputRejected, match="not finite"):
        report_from_msg(_location_msg(13.0, 500.0, 20.0, lo=math.nan))
    with pytest.raises(InputRejected, match="ahead of the max safe"):
        report_from_msg(_location_msg(13.0, 500.0, 20.0, lo=503.0))
    with pytest.raises(InputRejected, match="ahead of the max safe"):
        report_from_msg(_location_msg(13.0, 500.0, 20.0), orientation=-1)
    assert report_from_msg(_location_msg(13.0, math.nan, 0.0, mode=0)).has_position is False
    from train_localization.core.convert import etcs_event_from_msg as event_from_msg
    from train_localization_msgs.msg import EtcsEvent
    ev = EtcsEvent(kind=EtcsEvent.KIND_OUTSIDE_WINDOW, nid_bg="BG8", reaction=EtcsEvent.REACTION_TRAIN_TRIP,
                   detail="read 30 m early")
    ev.header.stamp.sec = 14
    assert event_from_msg(ev) == LocationEvent(14.0, EventKind.OUTSIDE_WINDOW, "BG8", Reaction.TRAIN_TRIP,
                                               "read 30 m early")
    ev.reaction = 7
    with pytest.raises(InputRejected, match="unknown"):
        event_from_msg(ev)


def test_the_node_commands_brakes_from_the_reports_and_counts_a_refused_one(ros_context, start_node):
    from diagnostic_msgs.msg import DiagnosticArray
    from train_localization_msgs.msg import AtpCommand, EtcsLocation
    from train_localization.nodes.common import STREAM_QOS

    proc = start_node("atp_supervision", "--ros-args", "-r", "__ns:=/train", "-p", "end_of_authority:=1000.0",
                      "-p", "start_braked:=false")
    node = ros_context.create_node("probe_atp_supervision", namespace="/train")
    pub = node.create_publisher(EtcsLocation, "localization/etcs", STREAM_QOS)
    commands, diags = [], []
    node.create_subscription(AtpCommand, "atp/command", commands.append, STREAM_QOS)
    node.create_subscription(DiagnosticArray, "/diagnostics", diags.append, 10)

    def own_status():
        found = [st for arr in diags for st in arr.status if "atp_supervision" in st.name]
        return found[-1] if found else None

    try:
        assert spin_until(node, lambda: pub.get_subscription_count() > 0
                          and node.count_publishers("/train/atp/command") > 0, 30.0), proc.output()
        spin_until(node, lambda: False, 0.5)                  # both directions matched
        # stamps far enough apart that each front is within kinematic reach of the one before
        for m in [_location_msg(10.0, 300.0, 20.0),           # 698 m to the EOA: normal
                  _location_msg(11.0, 400.0, 20.0, lo=math.nan),   # refused: nan
                  _location_msg(23.0, 560.0, 20.0),           # 438 m < SBI 451 m: service brake
                  _location_msg(33.0, 1003.0, 20.0),          # min safe front end 1001 m: trip
                  _location_msg(33.1, 3000.0, 0.0)]:          # refused: motion (2 km in 0.1 s, at rest)
            pub.publish(m)
        assert spin_until(node, lambda: len(commands) >= 3, 20.0), proc.output()
        assert [(c.status, c.brake) for c in commands] == [
            (AtpCommand.STATUS_NORMAL, AtpCommand.BRAKE_NONE),
            (AtpCommand.STATUS_INTERVENTION, AtpCommand.BRAKE_SERVICE),
            (AtpCommand.STATUS_TRIP, AtpCommand.BRAKE_EMERGENCY)]
        assert commands[1].distance_to_eoa == pytest.approx(438.0) and commands[1].end_of_authority == 1000.0
        assert commands[2].header.stamp.sec == 33 and commands[0].track_id == "test"

        def counted():
            st = own_status()
            values = {kv.key: kv.value for kv in st.values} if st else {}
            return values.get("rejected/localization/etcs/nan") == "1" and values.get("trips") == "1" \
                and values.get("rejected/localization/etcs/motion") == "1"
        assert spin_until(node, counted, 20.0), proc.output()
        st = own_status()
        values = {kv.key: kv.value for kv in st.values}
        assert values["accepted/localization/etcs"] == "3" and values["status"] == "TRIP"
        assert st.level == bytes([2]) and "trip" in st.message
        assert proc.proc.poll() is None
        assert proc.interrupt() == 0
        assert "Traceback" not in proc.output()
    finally:
        node.destroy_node()


def test_the_speed_controller_node_brakes_while_the_atp_commands_it(ros_context, start_node):
    from std_msgs.msg import Float64
    from diagnostic_msgs.msg import DiagnosticArray
    from train_localization_msgs.msg import AtpCommand, TrainState
    from train_localization.nodes.common import STREAM_QOS

    proc = start_node("speed_controller", "--ros-args", "-r", "__ns:=/train", "-p",
                      f"scenario:={ROOT / 'config' / 'scenario_rig.yaml'}")
    node = ros_context.create_node("probe_speed_controller_atp", namespace="/train")
    atp_pub = node.create_publisher(AtpCommand, "atp/command", STREAM_QOS)
    state_pub = node.create_publisher(TrainState, "localization/state", STREAM_QOS)
    traction, brakes, diags = [], [], []
    node.create_subscription(Float64, "control/traction", lambda m: traction.append(m.data), STREAM_QOS)
    node.create_subscription(Float64, "control/brake", lambda m: brakes.append(m.data), STREAM_QOS)
    node.create_subscription(DiagnosticArray, "/diagnostics", diags.append, 10)

    def accepted_commands() -> str | None:
        return _diag_values(diags, "speed_controller").get("accepted/atp/command")

    def state(t: float, speed: float):
        m = TrainState(speed=speed, speed_stddev=0.01, mode=1)
        m.header.stamp.sec, m.header.stamp.nanosec = int(t), int(round((t % 1) * 1e9))
        return m

    try:
        assert spin_until(node, lambda: atp_pub.get_subscription_count() > 0 and state_pub.get_subscription_count() > 0
                          and node.count_publishers("/train/control/traction") > 0, 30.0), proc.output()
        spin_until(node, lambda: False, 0.5)
        atp_pub.publish(AtpCommand(status=AtpCommand.STATUS_INTERVENTION, brake=AtpCommand.BRAKE_EMERGENCY,
                                   reason="test"))
        atp_pub.publish(AtpCommand(brake=7))                   # refused: the brake stands
        assert spin_until(node, lambda: accepted_commands() == "1", 20.0), proc.output()
        state_pub.publish(state(5.0, 10.0))
        assert spin_until(node, lambda: len(traction) >= 1 and len(brakes) >= 2, 20.0), proc.output()
        assert traction[0] == 0.0 and brakes[:2] == [1.0, 1.0]
        atp_pub.publish(AtpCommand(brake=AtpCommand.BRAKE_NONE))
        assert spin_until(node, lambda: accepted_commands() == "2", 20.0), proc.output()
        state_pub.publish(state(5.1, 10.0))                    # set-point 55 km/h: the PID accelerates
        assert spin_until(node, lambda: len(traction) >= 2, 20.0), proc.output()
        assert traction[1] > 0.0 and brakes[-1] == 0.0
        assert _diag_values(diags, "speed_controller")["rejected/atp/command/brake"] == "1"
        assert proc.interrupt() == 0
    finally:
        node.destroy_node()



def test_location_reports_that_stop_are_an_emergency_brake_whatever_the_last_one_said():
    """A stale report stream is "position unknown": the emergency brake, also when the last
    report claimed a standstill (the last thing a failing node or an attacker sent)."""
    sup = _sup()
    assert sup.check_stale(5.0) is None                          # no report yet: nothing to judge
    sup.update(_report(2.0, 100.0, 20.0))
    assert sup.check_stale(0.9) is None                          # within report_timeout (1 s)
    d = sup.check_stale(1.2)
    assert (d.status, d.brake) == (Status.INTERVENTION, Brake.EMERGENCY) and "position unknown" in d.reason
    assert d.t == pytest.approx(3.2) and sup.stats["intervention_stale"] == 1
    assert sup.check_stale(2.0) is None                          # already braking: once
    at_rest = _sup()
    at_rest.update(_report(1.0, 100.0, 0.0))
    assert at_rest.check_stale(1.2).brake == Brake.EMERGENCY     # last seen at rest: braked all the same
    assert at_rest.update(_report(3.0, 100.0, 0.0)).brake == Brake.EMERGENCY   # held until a confirmed standstill
    assert at_rest.update(_report(4.0, 100.0, 0.0)).brake == Brake.NONE


def test_a_supervision_starts_braked_and_releases_at_a_confirmed_standstill_with_or_without_a_position():
    """start_braked (default): a supervision (re)started while the train moves keeps the
    emergency brake until the standstill is confirmed; at the start of a mission, initialising
    reports at rest release it after standstill_confirmation."""
    sup = Supervision({"end_of_authority": EOA})
    assert sup.update(_report(1.0, 100.0, 15.0)).brake == Brake.EMERGENCY     # restarted while moving
    assert sup.update(_report(5.0, 150.0, 0.0)).brake == Brake.EMERGENCY
    assert sup.update(_report(6.0, 150.0, 0.0)).brake == Brake.NONE
    fresh = Supervision({"end_of_authority": EOA})
    assert fresh.update(_report(0.0, math.nan, 0.0, mode=0)).brake == Brake.EMERGENCY
    assert fresh.update(_report(0.5, math.nan, 0.0, mode=0)).brake == Brake.EMERGENCY
    d = fresh.update(_report(1.0, math.nan, 0.0, mode=0))
    assert (d.brake, fresh.stats["interventions"]) == (Brake.NONE, 0)


def test_one_report_of_a_standstill_during_a_brake_releases_nothing():
    """A report with v_est 0 between two real ones while the train brakes from 20 m/s: the
    supervision keeps the brake (no confirmed standstill); the admission refuses it outright
    (motion: 0 m/s is out of reach 0.1 s after 20 m/s)."""
    from train_localization.core.etcs.admission import SupervisionAdmission
    sup, guard = _sup(), SupervisionAdmission({}, 1, 1.0)
    for t, front, v in ((1.0, EOA - 300.0, 20.0), (1.1, EOA - 298.0, 19.9)):
        assert guard.report(_report(t, front, v), t) is None
        assert sup.update(_report(t, front, v)).brake == Brake.EMERGENCY
    spoof = _report(1.15, EOA - 297.0, 0.0)
    refusal = guard.report(spoof, 1.15)
    assert refusal is not None and refusal.reason == "motion" and guard.reports.refused == {"motion": 1}
    assert sup.update(spoof).brake == Brake.EMERGENCY            # even if it got through: one report
    assert sup.update(_report(1.2, EOA - 296.0, 19.8)).brake == Brake.EMERGENCY
    assert sup.stats["releases"] == 0
