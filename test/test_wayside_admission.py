"""What the wayside consumers of the fused state admit (docs/reliability.md, issue 48): the
association's fused states and track hypotheses (core/association.py TrainInputs over
core/safety/fused_state.py), switch positions (core/convert.py), the section-occupancy streams of
the voting and the changeover controller (core/wayside/occupancy.py) and the cross-check's
inputs (core/wayside/crosscheck.py); each refusal counted by reason, each stale stream answered
by the node's safe reaction. At the end the association node over DDS."""
from __future__ import annotations

import math
import tracemalloc
from types import SimpleNamespace

import pytest

from train_localization.core import convert
from train_localization.core.association import (MAX_PATH_ENTRIES, MAX_PENDING, MAX_STATES, TRACK_BUDGET, USED,
                                                 AMBIGUOUS, Associator, FusedState, TrainInputs)
from train_localization.core.fusion import MODE_INITIALISING, MODE_NOMINAL
from train_localization.core.measurements import CLEAR, DISTURBED, OCCUPIED, PositionFix, SectionOccupancy, SectionState
from train_localization.core.network import Network
from train_localization.core.network.config import MAX_HYPOTHESES
from train_localization.core.paths import resolve
from train_localization.core.safety.admission import MAX_ITEMS
from train_localization.core.wayside.catenary import ABB1, ABB2
from train_localization.core.wayside.crosscheck import CrossCheckInputs
from train_localization.core.wayside.neutral_section import ChangeoverController
from train_localization.core.wayside.occupancy import SILENT, CombinedOccupancy, SectionMap
from train_localization.core.signals import InputRejected

NOW = 1000.0     # the consumer's clock at the first state [s]


@pytest.fixture(scope="module")
def throat():
    return Network.from_yaml(resolve("config/track_throat.yaml"))


def state(t, front, v=25.0, half=5.0, mode=MODE_NOMINAL, track="test_line", sd_v=0.1):
    return FusedState(t, front, front - half, front + half, v, sd_v, mode, (), track, 0.999)


def admit_run(inputs, t0=NOW, n=200, front0=1000.0, v=25.0, dt=0.005, track="test_line"):
    """n real states at 1/dt Hz, each arriving at its stamp; all admitted."""
    for k in range(n):
        t = t0 + k * dt
        assert inputs.state(state(t, front0 + v * k * dt, v, track=track), t) is None
    return t0 + (n - 1) * dt, front0 + v * (n - 1) * dt


# ---------------------------------------------------------------- the association's fused states

def test_the_association_refuses_each_spoofed_state_and_keeps_the_real_stream():
    lead = TrainInputs("lead")
    t, x = admit_run(lead)
    attacks = [
        (state(t + 0.005, x + 5000.0), "motion"),                   # the train 5 km on
        (state(t + 0.005, x + 0.125, v=0.0), "motion"),             # a standstill at 25 m/s
        (state(t + 50.0, x), "future"),                             # stamped 50 s ahead
        (state(t + 1e6, x, v=0.0), "future"),
        (state(t - 0.5, x - 12.5), "stamp_back"),
        (state(t, x), "duplicate"),
        (state(t + 0.005, math.nan), "nan"),
        (FusedState(t + 0.005, x, x + 5.0, x - 5.0, 25.0, 0.1, MODE_NOMINAL, (), "test_line"), "implausible"),
        (state(t + 0.005, x, v=300.0), "implausible"),
        (state(t + 0.005, x, track="t" * 65), "too_long"),
    ]
    for s, why in attacks:
        refusal = lead.state(s, t + 0.005)
        assert refusal is not None and refusal.reason == why, (s, refusal)
        assert "\n" not in str(refusal)
    big = lead.state(state(t + 0.005, x + 0.125), t + 0.005, {"sensors": MAX_ITEMS + 1})
    assert big.reason == "too_large"
    assert lead.refused()["state"] == {"motion": 2, "future": 2, "stamp_back": 1, "duplicate": 1, "nan": 1,
                                       "implausible": 2, "too_long": 1, "too_large": 1}
    assert len(lead.states) == 200 and lead.states[-1].stamp == t          # none of them kept
    # the real stream goes on; a state claiming no position is taken and is no reference
    assert lead.state(state(t + 0.01, x + 0.25), t + 0.01) is None
    assert lead.state(state(t + 0.015, math.nan, mode=MODE_INITIALISING), t + 0.015) is None
    assert lead.state(state(t + 0.02, x + 0.5), t + 0.02) is None
    assert lead.state_stream.stream.admitted == 203
    # the fix of the real front goes to it, one at the spoofed place to nobody
    assoc = Associator({"lead": lead.states}, {"lead": "test_line"})
    fix = lambda pos: PositionFix(t + 0.02, "axle_counter", "ac", "test_line", "AC1", pos, 0.5, 1)
    assert assoc.associate(fix(x + 1.0)) == "lead" and assoc.associate(fix(x + 5000.0)) is None


def test_a_stale_train_explains_every_fix_after_its_last_state():
    """A train whose stream is stale may be anywhere after its last admitted state: a fix there is
    ambiguous rather than given to the other train; a fix within its states is judged as before."""
    lead, follow = TrainInputs("lead"), TrainInputs("follow")
    t, _ = admit_run(lead, front0=1000.0)
    admit_run(follow, front0=500.0)
    assert not lead.stale(t + 1.0) and lead.stale(t + 1.01)      # input_timeout 1 s of the node clock
    assoc = Associator({"lead": lead.states, "follow": follow.states}, {"lead": "test_line", "follow": "test_line"})
    late = PositionFix(t + 3.0, "axle_counter", "ac", "test_line", "AC1", 524.875 + 75.0, 0.5, 1)   # follow's place
    assert assoc.associate(late) == "follow"
    assert assoc.associate(late, stale={"lead"}) is None and assoc.decisions[-1].candidates == ("lead", "follow")
    within = PositionFix(t - 0.2, "axle_counter", "ac", "test_line", "AC1", 1020.0, 0.5, 1)
    assert assoc.associate(within, stale={"lead"}) == "lead"
    assert assoc.associate(PositionFix(t - 0.2, "axle_counter", "ac", "test_line", "AC1", 700.0, 0.5, 1),
                           stale={"lead"}) is None                # nobody's, stale or not
    assert assoc.counts == {USED: 2, AMBIGUOUS: 1, "unexplained": 1}


def test_a_stream_refused_or_silent_past_its_time_out_is_stale_until_a_real_state_comes():
    lead = TrainInputs("lead")
    lead.state_stream.waiting_since(NOW)
    assert not lead.stale(NOW + 1.0) and lead.stale(NOW + 1.5)   # never a state: stale after the time-out
    t, x = admit_run(lead, t0=NOW + 2.0)
    for k in range(1, 300):                                       # spoofed ones only, for 1.5 s
        assert lead.state(state(t + 0.005 * k, x + 3000.0), t + 0.005 * k).reason == "motion"
    assert lead.stale(t + 1.5) and lead.refused()["state"]["motion"] == 299
    assert lead.state(state(t + 1.5, x + 37.5), t + 1.5) is None and not lead.stale(t + 1.5)


# ---------------------------------------------------------------- on a network

def hyp(track, position, half=4.0, speed=12.0, path=None, probability=1.0):
    path = list(path or [track])
    return SimpleNamespace(track_id=track, position=position, speed=speed, position_min=position - half,
                           position_max=position + half, probability=probability, path=path,
                           pieces=[(position - half, position + half)] * len(path))


def test_network_states_are_restated_across_a_section_change_and_a_far_section_refused(throat):
    north = TrainInputs("north", network=throat)
    t = NOW
    for k in range(40):                                 # T1 990 m -> over W1 onto the crossover T3
        t, front = NOW + 0.1 * k, 990.0 + 1.2 * k
        track, chainage = ("T1", front) if front < 1000.0 else ("T3", front - 1000.0)
        assert north.state(state(t, chainage, v=12.0, track=track), t) is None, (k, track, chainage)
    assert north.state_stream.section == "T3"
    # T3's end joins T5's begin through W2: 58.5 m on; T6 lies 400 m beyond, T4 runs the other way
    assert north.state(state(t + 0.1, 1.0, v=12.0, track="T5"), t + 0.1).reason == "motion"
    assert north.state(state(t + 0.1, 500.0, v=12.0, track="T6"), t + 0.1).reason == "motion"
    assert north.state(state(t + 0.1, 700.0, v=-12.0, track="T4"), t + 0.1).reason == "motion"
    assert north.state(state(t + 0.1, 1.0, v=12.0, track="T9"), t + 0.1).reason == "unknown_id"
    # the real train reaches T5 (path length 58.54 m of T3)
    x = 46.8 + 1.2
    assert north.state(state(t + 0.1, x, v=12.0, track="T3"), t + 0.1) is None
    for k in range(1, 20):
        front = x + 1.2 * k
        track, chainage = ("T3", front) if front < 58.538631665498 else ("T5", front - 58.538631665498)
        assert north.state(state(t + 0.1 + 0.1 * k, chainage, v=12.0, track=track), t + 0.1 + 0.1 * k) is None
    assert north.state_stream.section == "T5"
    assert north.refused()["state"] == {"motion": 3, "unknown_id": 1}


def test_the_most_probable_hypothesis_changing_between_branches_is_no_jump(throat):
    """Past W1 the fused state's section is that of its most probable hypothesis, T2 (track A)
    or T3 (the crossover): both leave W1 on its B side, so they share the distance run."""
    north = TrainInputs("north", network=throat)
    for k in range(10):
        t = NOW + 0.1 * k
        track = ("T2", "T3")[k % 2]
        assert north.state(state(t, 20.0 + 1.2 * k, v=12.0, track=track), t) is None, k
    t = NOW + 1.0
    assert north.state(state(t, 20.0 + 1.2 * 10 + 30.0, v=12.0, track="T3"), t).reason == "motion"   # 30 m on
    assert north.state(state(t, 1000.0 - 32.0, v=12.0, track="T1"), t).reason == "motion"    # back before W1
    assert north.state(state(t, 32.0, v=12.0, track="T2"), t) is None


def test_track_hypotheses_of_unbounded_size_are_refused_in_one_line(throat):
    north = TrainInputs("north", network=throat)
    assert north.max_path == 7                                  # the throat's sections
    ok = [hyp("T3", 20.0, path=["T3"]), hyp("T2", 20.0, path=["T2"])]
    long_path = ["T1", "T3", "T5", "T6"] * 2                    # 8 sections of a network of 7
    attacks = [
        ((NOW, "throat", [hyp("T1", 10.0, path=long_path)]), "too_large"),
        ((NOW, "throat", [hyp("T1", 10.0, path=["T1"] * 2000)] * 256), "too_large"),   # the +220 MB message
        ((NOW, "throat", ok * (MAX_HYPOTHESES // 2 + 1)), "too_large"),                  # 258 hypotheses
        ((NOW, "throat", [hyp("T1", 10.0, path=["T1", "T3", "T5"])] * 342), "too_large"),
        ((NOW, "throat", [hyp("T9", 10.0)]), "unknown_id"),
        ((NOW, "throat", [hyp("T1", 10.0, path=["T1", "T9"])]), "unknown_id"),
        ((NOW, "yard", ok), "unknown_id"),
        ((NOW, "n" * 65, ok), "too_long"),
        ((NOW + 60.0, "throat", ok), "future"),
        ((math.nan, "throat", ok), "nan"),
    ]
    for (stamp, network_id, hyps), why in attacks:
        refusal = north.tracks(stamp, network_id, hyps, NOW)
        assert refusal is not None and refusal.reason == why, (why, len(hyps), refusal)
        assert "\n" not in str(refusal) and len(str(refusal)) < 200
    assert north.refused()["tracks"] == {"too_large": 4, "unknown_id": 3, "too_long": 1, "future": 1, "nan": 1}
    assert 4 * 200 <= MAX_PATH_ENTRIES < 3 * 342
    assert north.track_stream.admitted == 0
    # 800 sections in all, each path within the network's 7: taken
    assert north.tracks(NOW, "throat", [hyp("T1", 10.0, path=["T1", "T3", "T5", "T6"])] * 200, NOW) is None
    assert north.tracks(NOW, "throat", ok, NOW).reason == "duplicate"
    assert north.tracks(NOW - 1.0, "throat", ok, NOW).reason == "stamp_back"


def test_hypotheses_are_joined_by_stamp_and_kept_within_bounds(throat):
    north = TrainInputs("north", network=throat)
    # hypotheses before their state (pending) and after it, joined to the state of their stamp
    assert north.tracks(NOW, "throat", [hyp("T1", 500.0)], NOW) is None
    assert north.state(state(NOW, 500.0, v=12.0, track="T1"), NOW) is None
    assert north.state(state(NOW + 0.1, 501.2, v=12.0, track="T1"), NOW + 0.1) is None
    assert north.tracks(NOW + 0.1, "throat", [hyp("T1", 501.2)], NOW + 0.1) is None
    assert [len(s.hypotheses) for s in north.states] == [1, 1] and north.kept == 2
    assert north.states[0].hypotheses[0].path == ("T1",)
    assert north.states[0].hypotheses[0].path[0] is next(k for k in throat.sections if k == "T1")   # interned
    # hypotheses whose state never comes: at most MAX_PENDING kept, none older than the last state
    for k in range(1, 40):
        assert north.tracks(NOW + 0.1 + 0.005 * k, "throat", [hyp("T1", 501.2)], NOW + 0.1) is None
    assert len(north.pending) == MAX_PENDING
    assert north.state(state(NOW + 0.3, 503.6, v=12.0, track="T1"), NOW + 0.3) is None
    assert not north.pending
    # a flood of messages of 256 hypotheses: at most TRACK_BUDGET hypotheses kept, the oldest dropped
    tracemalloc.start()
    before = tracemalloc.get_traced_memory()[0]
    t = NOW + 0.3
    for k in range(1, 401):
        t = NOW + 0.3 + 0.005 * k
        front = 503.6 + 12.0 * 0.005 * k
        many = [hyp("T1", front + 1e-3 * j, path=["T1", "T2", "T3", "T4", "T5", "T6", "T7"][:1 + j % 7])
                for j in range(MAX_HYPOTHESES)]
        assert north.tracks(t, "throat", many, t) is None
        assert north.state(state(t, front, v=12.0, track="T1"), t) is None
    grown = tracemalloc.get_traced_memory()[0] - before
    tracemalloc.stop()
    assert north.kept <= TRACK_BUDGET and north.kept == 64 * MAX_HYPOTHESES
    carrying = [s for s in north.states if s.hypotheses]
    assert len(carrying) == 64 and carrying[-1].stamp == t
    dropped = [s for s in north.states if s.hypotheses is None]
    assert len(dropped) == 2 + 400 - 64 and max(s.stamp for s in dropped) < carrying[0].stamp
    assert grown < 8e6, grown        # 4.6 MB measured (docs/nodes.md)
    # a fix older than the kept hypotheses: the train may be anywhere then (a candidate, as before
    # its first state), so the fix is ambiguous with another train there rather than misrouted
    other = TrainInputs("south", network=throat)
    assert other.state(state(NOW + 0.5, 520.0, v=12.0, track="T1"), NOW + 0.5) is None
    assert other.tracks(NOW + 0.5, "throat", [hyp("T1", 520.0)], NOW + 0.5) is None
    assoc = Associator({"north": north.states, "south": other.states}, {}, network=throat)
    assert assoc.associate(PositionFix(NOW + 0.5, "axle_counter", "ac", "T1", "X", 520.0, 0.05, 1)) is None
    assert assoc.decisions[-1].candidates == ("north", "south")


def test_states_are_kept_within_the_history_and_a_count(throat):
    lead = TrainInputs("lead", history=10.0)
    admit_run(lead, n=MAX_STATES + 500, dt=0.001)        # a flood of plausible states at 1 kHz
    assert len(lead.states) == MAX_STATES
    slow = TrainInputs("slow", history=1.0)
    admit_run(slow, n=500, dt=0.01)
    assert slow.states[-1].stamp - slow.states[0].stamp <= 2.0


# ---------------------------------------------------------------- switch positions

def test_switch_positions_of_more_entries_than_switches_are_refused(throat):
    from train_localization.core.bagio import typestore_classes
    mc = typestore_classes()
    n = len(throat.switches())
    flood = mc.SwitchPositions(header=mc.header(0.0), switch_ids=[f"W{k}" for k in range(200_000)],
                               positions=["B1"] * 200_000)
    with pytest.raises(InputRejected, match="200000 entries") as exc:
        convert.switch_positions_from_msg(flood)
    assert exc.value.reason == "too_large" and "\n" not in str(exc.value)
    four = convert.switch_positions_to_msg(mc, 0.0, {"W1": "B1", "W2": "B2", "W3": "", "W4": "B1"})
    with pytest.raises(InputRejected, match="at most 3"):
        convert.switch_positions_from_msg(four, n)
    three = convert.switch_positions_to_msg(mc, 0.0, {"W1": "B1", "W2": "B2", "W3": ""})
    assert convert.switch_positions_from_msg(three, n) == {"W1": "B1", "W2": "B2", "W3": ""}
    assert len(convert.switch_positions_from_msg(four)) == 4          # the default bound: MAX_ITEMS


# ---------------------------------------------------------------- section occupancy

def report(stamp, source, states, start=0.0):
    return SectionOccupancy(stamp, source, tuple(SectionState(sid, start, 1.0, st, 0, 0, 0)
                                                 for sid, st in states.items()))


def test_occupancy_reports_are_admitted_per_system_and_counted():
    occ = CombinedOccupancy(SectionMap.fig6())
    tc, ac = occ.streams["track_circuit"], occ.streams["axle_counter"]
    assert occ.update(report(10.0, "track_circuit", {"TC1": CLEAR, "TC2": CLEAR}), 10.0)
    assert occ.update(report(10.0, "axle_counter", {"S1": CLEAR, "S2": CLEAR}), 10.0)
    assert occ.update(report(10.0, "axle_counter", {"S1": OCCUPIED, "S2": CLEAR}), 10.0)   # same instant: taken
    attacks = [
        (report(9.0, "axle_counter", {"S1": CLEAR, "S2": CLEAR}), "stamp_back"),    # an old CLEAR replayed
        (report(20.0, "axle_counter", {"S1": CLEAR, "S2": CLEAR}), "future"),
        (report(math.nan, "axle_counter", {"S1": CLEAR}), "nan"),
        (report(10.1, "axle_counter", {"S1": CLEAR}, start=math.inf), "nan"),
        (report(10.1, "axle_counter", {"S1": 7}), "implausible"),
        (report(10.1, "axle_counter", {f"S{k}": CLEAR for k in range(MAX_ITEMS + 1)}), "too_large"),
        (SectionOccupancy(10.1, "axle_counter" , (SectionState("S" * 65, 0.0, 1.0, CLEAR, 0, 0, 0),)), "too_long"),
    ]
    for r, why in attacks:
        assert not occ.update(r, 10.1)
        assert occ.refusal is not None and occ.refusal.reason == why, (why, occ.refusal)
    assert occ.update(report(10.2, "axle_counter", {"S1": OCCUPIED, "S2": CLEAR}), 10.2)
    assert not occ.update(report(10.3, "lzb", {}), 10.3) and occ.refusal is None and occ.ignored == 1
    assert ac.refused == {"stamp_back": 1, "future": 1, "nan": 2, "implausible": 1, "too_large": 1, "too_long": 1}
    assert (ac.admitted, tc.admitted, sum(tc.refused.values())) == (3, 1, 0)
    s1, s2 = occ.evaluate(10.3)
    assert (s1.state, s1.ac, s2.state) == (OCCUPIED, OCCUPIED, CLEAR)   # none of the refused ones counted


def test_a_stale_system_never_makes_a_section_clear():
    """The axle counter keeps sending, but only reports stamped ahead (refused): 2.5 s after its
    last admitted one it is silent and no section is CLEAR; the track circuit alone says CLEAR."""
    occ = CombinedOccupancy(SectionMap.fig6())
    for k in range(3):
        t = 10.0 + k
        occ.update(report(t, "track_circuit", {"TC1": CLEAR, "TC2": CLEAR}), t)
        occ.update(report(t, "axle_counter", {"S1": CLEAR, "S2": CLEAR}), t)
    assert [s.state for s in occ.evaluate(12.0)] == [CLEAR, CLEAR]
    for k in range(1, 31):
        t = 12.0 + 0.1 * k
        occ.update(report(t, "track_circuit", {"TC1": CLEAR, "TC2": CLEAR}), t)
        assert not occ.update(report(t + 100.0, "axle_counter", {"S1": CLEAR, "S2": CLEAR}), t)
        sections = occ.evaluate(t)
        if t <= 14.5 + 1e-9:
            assert [s.state for s in sections] == [CLEAR, CLEAR], t
        else:
            assert [(s.state, s.ac, s.degraded) for s in sections] == [(DISTURBED, SILENT, True)] * 2, t
    assert occ.streams["axle_counter"].refused == {"future": 30}
    # a report of its sections stamped in time, but delivered late (its stamp 3 s old): still silent
    occ.update(report(12.5, "axle_counter", {"S1": CLEAR, "S2": CLEAR}), 15.0)
    assert occ.evaluate(15.5)[0].state == DISTURBED
    # an occupied one decides even alone (degraded): OCCUPIED, never CLEAR
    occ.update(report(15.6, "track_circuit", {"TC1": OCCUPIED, "TC2": CLEAR}), 15.6)
    assert [s.state for s in occ.evaluate(15.6)] == [OCCUPIED, DISTURBED]


def test_the_changeover_goes_dead_when_a_systems_stream_is_stale():
    """Seed 004 section 4.1's safe side (docs/changeover.md): with a system stale the neutral
    section is switched dead (both ABBs open), whatever the systems said last."""
    occ = CombinedOccupancy(SectionMap.fig6())
    ctrl = ChangeoverController({"recover_time": 0.5})
    t = 0.0
    for k in range(21):
        t = 0.1 * k
        occ.update(report(t, "track_circuit", {"TC1": CLEAR, "TC2": CLEAR}), t)
        if k < 10:
            occ.update(report(t, "axle_counter", {"S1": CLEAR, "S2": CLEAR}), t)
        ctrl.update(t, occ.evaluate(t))
    assert ctrl.mode == "IDLE" and ctrl.abb == {ABB1: True, ABB2: False}    # 1.1 s since its last report
    for k in range(1, 20):
        t = 2.0 + 0.1 * k
        occ.update(report(t, "track_circuit", {"TC1": CLEAR, "TC2": CLEAR}), t)
        occ.update(report(0.5, "axle_counter", {"S1": CLEAR, "S2": CLEAR}), t)   # an old one replayed: stamp_back
        ctrl.update(t, occ.evaluate(t))
    assert ctrl.safe and ctrl.abb == {ABB1: False, ABB2: False} and "SILENT" in ctrl.reason
    assert occ.streams["axle_counter"].refused["stamp_back"] == 19
    assert 3.4 - 1e-9 <= ctrl.safe_entries[0][0] <= 3.5   # its last report at 0.9 s + input_timeout 2.5 s


# ---------------------------------------------------------------- the cross-check

def test_the_crosscheck_refuses_spoofed_states_and_warns_on_a_stale_stream():
    x1 = 1800.0
    inputs = CrossCheckInputs("t1", {"persist": 0.0})
    inputs.waiting_since(NOW)
    flags, stale = inputs.evaluate(NOW)
    assert not flags and stale == ["no fused state of train t1 admitted yet", "no combined occupancy admitted yet"]
    combined = lambda t: SectionOccupancy(t, "combined", (SectionState("S1", 1000.0, x1, OCCUPIED, 0, 0, 0),
                                                          SectionState("S2", x1, 2600.0, CLEAR, 0, 0, 0)))
    t = NOW
    for k in range(20):
        t = NOW + 0.05 * k
        assert inputs.state(state(t, 1700.0 + 20.0 * 0.05 * k, v=20.0), t) is None
        if k % 10 == 0:
            assert inputs.occupancy(combined(t), t) is None
    flags, stale = inputs.evaluate(t)
    assert not flags and not stale                          # the train in S1, which is occupied: OK
    # a spoofed state in S2 (the train 500 m on) and a standstill: refused, the claim unchanged
    assert inputs.state(state(t + 0.05, 2219.0, v=20.0), t + 0.05).reason == "motion"
    assert inputs.state(state(t + 0.05, 1720.0, v=0.0), t + 0.05).reason == "motion"
    assert inputs.occupancy(combined(t + 30.0), t + 0.05).reason == "future"
    assert inputs.occupancy(combined(NOW), t + 0.05).reason == "stamp_back"
    assert inputs.states.stream.refused == {"motion": 2} and inputs.combined.refused == {"future": 1, "stamp_back": 1}
    assert inputs.evaluate(t + 0.05) == ([], [])
    # silence past input_timeout (1 s): stale, a WARN; the claim is what the last state still
    # allows (moving on into S2 at up to 20 m/s + 5 m/s^2): no claims_clear, no unclaimed flag
    flags, stale = inputs.evaluate(t + 1.2)
    assert stale == ["no fused state of train t1 admitted for 1.2 s"] and not flags
    inputs.occupancy(combined(t + 1.2), t + 1.2)
    # the occupancy silent past occupancy_timeout (2.5 s): stale too, the sections no longer compared
    flags, stale = inputs.evaluate(t + 3.8)
    assert stale == ["no fused state of train t1 admitted for 3.8 s", "no combined occupancy admitted for 2.6 s"]
    assert not flags


# ---------------------------------------------------------------- the association node over DDS

def test_the_association_node_refuses_oversized_hypotheses_and_a_far_state_and_keeps_routing(ros_context, tmp_path):
    """Over DDS: five TrackHypotheses of 256 hypotheses with 2,000-section paths and one state of
    north on T6 (1.5 km from where it is) are refused and counted (too_large 5, motion 1); the
    node keeps running and routes the fixes of the real states."""
    import os
    import subprocess
    import sys
    from conftest import spin_until
    from diagnostic_msgs.msg import DiagnosticArray
    from train_localization.nodes.common import STREAM_QOS, rclpy_classes
    log = open(tmp_path / "association.log", "w")
    assoc = subprocess.Popen([sys.executable, "-c", "from train_localization.nodes.association import main; main()",
                              "--ros-args", "-r", "__ns:=/wayside", "-p",
                              f"scenario:={resolve('config/scenario_throat_wayside.yaml')}"],
                             stdout=log, stderr=subprocess.STDOUT, start_new_session=True, env=dict(os.environ))
    mc = rclpy_classes()
    node = ros_context.create_node("association_admission_probe")
    routed: list = []
    status: dict[str, str] = {}
    try:
        states = node.create_publisher(mc.TrainState, "/north/localization/state", STREAM_QOS)
        tracks = node.create_publisher(mc.TrackHypotheses, "/north/localization/tracks", STREAM_QOS)
        south = node.create_publisher(mc.TrainState, "/south/localization/state", STREAM_QOS)
        south_tracks = node.create_publisher(mc.TrackHypotheses, "/south/localization/tracks", STREAM_QOS)
        fixes = node.create_publisher(mc.PositionFix, "/wayside/sensors/axle_counter/position", STREAM_QOS)
        node.create_subscription(mc.PositionFix, "/north/sensors/axle_counter/position",
                                 lambda msg: routed.append(msg.reference_id), STREAM_QOS)
        node.create_subscription(DiagnosticArray, "/diagnostics", lambda msg: status.update(
            {kv.key: kv.value for st in msg.status if "association" in st.name for kv in st.values}), 10)
        ready = [lambda: states.get_subscription_count() >= 1, lambda: tracks.get_subscription_count() >= 1,
                 lambda: fixes.get_subscription_count() >= 1, lambda: south.get_subscription_count() >= 1,
                 lambda: south_tracks.get_subscription_count() >= 1,
                 lambda: node.count_publishers("/north/sensors/axle_counter/position") >= 1]
        assert spin_until(node, lambda: all(f() for f in ready), timeout=60.0), \
            (tmp_path / "association.log").read_text()

        def est(t, hyps):
            return SimpleNamespace(stamp=t, hypotheses=[SimpleNamespace(
                track_id=h.track_id, position=h.position, speed=h.speed, position_min=h.position_min,
                position_max=h.position_max, probability=h.probability, path=h.path, pieces=h.pieces) for h in hyps])

        def send_state(t, track, position, speed=12.0, pub=states):
            pub.publish(convert.train_state_to_msg(mc, t, track, position, speed, 0.0, 1.0, 0.1, position - 4.0,
                                                      position + 4.0, 0.999, MODE_NOMINAL, []))
        for k in range(5):            # north on track A (T2) past W1, south on track B (T6)
            t = 10.0 + 0.1 * k
            x, y = 20.0 + 12.0 * (t - 10.0), 500.0 + 15.0 * (t - 10.0)
            send_state(t, "T2", x)
            send_state(t, "T6", y, 15.0, south)
            south_tracks.publish(convert.track_hypotheses_to_msg(mc, est(t, [hyp("T6", y, speed=15.0)]), "throat"))
            tracks.publish(convert.track_hypotheses_to_msg(mc, est(t, [hyp("T2", x)]), "throat"))
        huge = est(10.45, [hyp("T1", 500.0, path=["T1"] * 2000)] * MAX_HYPOTHESES)
        for k in range(5):
            huge.stamp = 10.45 + 0.001 * k
            tracks.publish(convert.track_hypotheses_to_msg(mc, huge, "throat"))
        send_state(10.45, "T6", 500.0)           # spoofed: 1.5 km away over W1 .. W3
        spin_until(node, lambda: False, timeout=0.5)
        t = 10.5
        send_state(t, "T2", 26.0)
        send_state(t, "T6", 507.5, 15.0, south)
        south_tracks.publish(convert.track_hypotheses_to_msg(mc, est(t, [hyp("T6", 507.5, speed=15.0)]), "throat"))
        tracks.publish(convert.track_hypotheses_to_msg(mc, est(t, [hyp("T2", 26.0)]), "throat"))
        spin_until(node, lambda: False, timeout=0.3)
        fixes.publish(convert.measurement_to_msg(
            PositionFix(10.2, "axle_counter", "axle_counter", "T2", "AC2", 22.4, 0.05, 1), mc))
        counted = {"rejected//north/localization/tracks/too_large": "5", "rejected//north/localization/state/motion": "1",
                   "accepted//north/localization/state": "6", "accepted//north/localization/tracks": "6"}
        done = spin_until(node, lambda: routed and all(status.get(k) == v for k, v in counted.items()), timeout=30.0)
        assert done, (routed, status, (tmp_path / "association.log").read_text()[-2000:])
        assert routed == ["AC2"] and assoc.poll() is None
        assert sum(int(v) for k, v in status.items() if k.startswith("rejected/")) == 6
    finally:
        node.destroy_node()
        assoc.terminate()
        assoc.wait(timeout=10)
        log.close()
