"""Combined wayside detection, the neutral-section changeover and the on-board / wayside
cross-check (seed 004 sections 4.1-4.2, Fig. 5-6): the voting table, the controller's
switching sequence in both directions against the detection events and the truth, no phase
bridging in nominal passages, and the injected faults (a poor-shunt train, a track circuit
stuck OCCUPIED, an axle counter DISTURBED, a silent system) each leading to the safe state or
to a correct detection by the other system."""
from __future__ import annotations

import math

import numpy as np
import pytest

from train_localization.core.measurements import CLEAR, DISTURBED, OCCUPIED, SectionOccupancy, SectionState
from train_localization.core.wayside import catenary
from train_localization.core.wayside.catenary import ABB1, ABB2, Layout, Switching
from train_localization.core.wayside.changeover_campaign import LAYOUTS, generate, summarise
from train_localization.core.wayside.crosscheck import Claim, CrossCheck
from train_localization.core.wayside.neutral_section import ChangeoverController
from train_localization.core.wayside.occupancy import (SILENT, CombinedOccupancy, CombinedSection, SectionMap,
                                                        to_occupancy, vote)
from train_localization.core.wayside.passage import BLOCK, Run, TrainSpec, simulate

LAYOUT = Layout.from_params({})
LATENCY = 0.01                   # Run.command_latency: decision -> ABB gate signal [s]
HALF_CYCLE = 0.5 / 60.0          # an opening ABB blocks at the next current zero
GAP = 0.1                        # changeover_gap: one ABB opened -> the other closes [s]
_RUNS: dict = {}


def kmh(v):
    return v / 3.6


def cached(key, make):
    """simulate(make()) once per key (the runs are shared between tests)."""
    if key not in _RUNS:
        run = make()
        _RUNS[key] = (run, simulate(run))
    return _RUNS[key]


def sim(direction=1, speed_kmh=200.0, kind="KTX", seed=1, train=None, **run_kw):
    """One train through the section: (train, RunResult)."""
    train = dict(train or {})
    key = (direction, speed_kmh, kind, seed, repr(sorted(train.items())), repr(sorted(run_kw.items())))

    def make():
        t = TrainSpec.of_type(kind, name="t1", direction=direction, entry_time=30.0, speed=kmh(speed_kmh), **train)
        return Run([t], seed=seed, **run_kw)
    run, result = cached(key, make)
    return run.trains[0], result


def first_change(log, section, system, value, after=-math.inf):
    """Stamp of the first occupancy-log entry after ``after`` where ``system`` (0 voted, 1 track
    circuit, 2 axle counter) of ``section`` has ``value``."""
    for stamp, states in log:
        if stamp > after and states[section][system] == value:
            return stamp
    return math.nan


def switch_sequence(result):
    return [(s.switch, s.on) for s in result.switchings]


# ---------------------------------------------------------------- voting

def test_voting_table_occupied_while_either_says_so():
    table = {
        (CLEAR, CLEAR): (CLEAR, False, False),
        (OCCUPIED, OCCUPIED): (OCCUPIED, False, False),
        (CLEAR, OCCUPIED): (OCCUPIED, True, False),       # seed 004 4.2: occupied while either says so
        (OCCUPIED, CLEAR): (OCCUPIED, True, False),
        (OCCUPIED, DISTURBED): (OCCUPIED, False, True),   # the track circuit alone detects the train
        (DISTURBED, OCCUPIED): (OCCUPIED, False, True),
        (CLEAR, DISTURBED): (DISTURBED, False, True),     # nobody can confirm clear
        (DISTURBED, CLEAR): (DISTURBED, False, True),
        (DISTURBED, DISTURBED): (DISTURBED, False, True),
        (SILENT, CLEAR): (DISTURBED, False, True),
        (CLEAR, SILENT): (DISTURBED, False, True),
        (SILENT, OCCUPIED): (OCCUPIED, False, True),
        (SILENT, SILENT): (DISTURBED, False, True),
    }
    for (tc, ac), expected in table.items():
        assert vote(tc, ac) == expected, (tc, ac)


def report(stamp, source, states):
    return SectionOccupancy(stamp, source, tuple(SectionState(sid, 0.0, 1.0, st, 0, 0, 0)
                                                 for sid, st in states.items()))


def test_disagreement_turns_into_a_contradiction_after_the_tolerance_and_silence_is_seen():
    occ = CombinedOccupancy(SectionMap.fig6())
    tol, timeout = occ.params["disagree_tolerance"], occ.params["input_timeout"]
    occ.update(report(0.0, "track_circuit", {"TC1": OCCUPIED, "TC2": CLEAR}))
    occ.update(report(0.0, "axle_counter", {"S1": CLEAR, "S2": CLEAR}))
    s1 = occ.evaluate(0.0)[0]
    assert (s1.state, s1.disagreement, s1.contradiction) == (OCCUPIED, True, False)
    occ.update(report(1.0, "track_circuit", {"TC1": OCCUPIED, "TC2": CLEAR}))
    occ.update(report(1.0, "axle_counter", {"S1": CLEAR, "S2": CLEAR}))
    assert not occ.evaluate(tol - 0.1)[0].contradiction
    occ.update(report(tol, "track_circuit", {"TC1": OCCUPIED, "TC2": CLEAR}))
    occ.update(report(tol, "axle_counter", {"S1": CLEAR, "S2": CLEAR}))
    assert occ.evaluate(tol + 0.1)[0].contradiction
    assert occ.records[0].text().startswith("S1: track circuit OCCUPIED, axle counter CLEAR")
    # the axle counter falls silent: its sections count as unknown
    occ.update(report(tol + timeout, "track_circuit", {"TC1": CLEAR, "TC2": CLEAR}))
    s1, s2 = occ.evaluate(tol + timeout + 0.5)
    assert (s1.ac, s1.state, s2.state) == (SILENT, DISTURBED, DISTURBED)
    assert not occ.update(report(0.0, "lzb", {}))


# ---------------------------------------------------------------- catenary

def test_catenary_counts_a_bridge_dead_time_and_an_air_section_switching():
    times = np.arange(0.0, 10.0, 0.01)
    x = LAYOUT.air2[0] - 100.0 + 20.0 * times            # one pantograph at 20 m/s towards B
    # the neutral stays on A: the pantograph bridges N (A) and B in air section 2
    rep = catenary.events(LAYOUT, [], times, {"t": x[:, None]}, {"t": False})
    assert len(rep.short_circuits) == 1 and "pantograph bridge" in rep.short_circuits[0]["cause"]
    t_in = (LAYOUT.air2[0] - x[0]) / 20.0
    t_out = (LAYOUT.air2[1] - x[0]) / 20.0
    assert rep.short_circuits[0]["start"] == pytest.approx(t_in, abs=0.011)
    assert rep.short_circuits[0]["end"] == pytest.approx(t_out, abs=0.011)
    # switched to B in time: no bridge; opened 1 s before the air section and closed in it
    log = [Switching(1.0, ABB1, False), Switching(t_in + 1.0, ABB2, True)]
    rep = catenary.events(LAYOUT, log, times, {"t": x[:, None]}, {"t": False})
    assert rep.short_circuits == []
    assert rep.dead["t"] == pytest.approx(t_in - 1.0, abs=0.02)
    assert [a["switch"] for a in rep.air_switchings] == [ABB2]
    assert rep.unfed["t"] == pytest.approx(t_in, abs=0.02)    # on the neutral from the start until B
    # a roof bus joins a pantograph on A to one on the neutral fed from B: the train is named
    both = np.column_stack([np.full_like(times, LAYOUT.air1[0] - 10.0), np.full_like(times, LAYOUT.ac[1])])
    log = [Switching(1.0, ABB1, False), Switching(1.1, ABB2, True)]
    rep = catenary.events(LAYOUT, log, times, {"t": both}, {"t": True})
    assert [c["cause"] for c in rep.short_circuits] == ["pantograph bridge: t (roof bus)"]
    assert rep.short_circuits[0]["start"] == pytest.approx(1.1, abs=0.011)
    # both ABBs closed: a short through the switches
    rep = catenary.events(LAYOUT, [Switching(1.0, ABB2, True)], times, {"t": x[:, None] * 0.0}, {"t": False})
    assert rep.short_circuits[0]["cause"] == "ABB-1 and ABB-2 closed"


# ---------------------------------------------------------------- the changeover, nominal

def rear_passes(train, x):
    """Time [s] the last axle passes chainage x."""
    entry = LAYOUT.ac[0] if train.direction > 0 else LAYOUT.ac[2]
    return train.time_at(abs(x - entry) + max(train.axles))


def front_passes(train, x):
    entry = LAYOUT.ac[0] if train.direction > 0 else LAYOUT.ac[2]
    return train.time_at(abs(x - entry) + min(train.axles))


@pytest.mark.parametrize("direction", [1, -1])
def test_changeover_sequence_follows_the_detection_in_both_directions(direction):
    train, r = sim(direction=direction)
    near, far = ("S1", "S2") if direction > 0 else ("S2", "S1")
    log = r.occupancy_log
    if direction > 0:
        # seed 004 4.1: ABB-1 off, ABB-2 on in the section, back when the train has left
        assert switch_sequence(r) == [(ABB1, False), (ABB2, True), (ABB2, False), (ABB1, True)]
        t_ac = first_change(log, near, 2, CLEAR, after=first_change(log, far, 0, OCCUPIED))
        t_tc = first_change(log, near, 1, CLEAR, after=t_ac - 1.0)
        t_exit = first_change(log, far, 0, CLEAR, after=t_tc)
        s = r.switchings
        assert s[0].stamp == pytest.approx(t_ac + LATENCY + HALF_CYCLE)       # first system to see S1 clear
        assert s[1].stamp == pytest.approx(max(t_tc, t_ac + GAP) + LATENCY)   # both systems see S1 clear
        assert s[2].stamp == pytest.approx(t_exit + LATENCY + HALF_CYCLE)     # S2 clear in both
        assert s[3].stamp == pytest.approx(t_exit + GAP + LATENCY)
    else:
        # entering S2 from B: the neutral goes to B at once, back to A after the middle, nothing at the exit
        assert switch_sequence(r) == [(ABB1, False), (ABB2, True), (ABB2, False), (ABB1, True)]
        t_in = first_change(log, near, 0, OCCUPIED)
        t_ac = first_change(log, near, 2, CLEAR, after=first_change(log, far, 0, OCCUPIED))
        t_tc = first_change(log, near, 1, CLEAR, after=t_ac - 1.0)
        s = r.switchings
        assert s[0].stamp == pytest.approx(t_in + LATENCY + HALF_CYCLE)
        assert s[1].stamp == pytest.approx(t_in + GAP + LATENCY)
        assert s[2].stamp == pytest.approx(t_ac + LATENCY + HALF_CYCLE)
        assert s[3].stamp == pytest.approx(max(t_tc, t_ac + GAP) + LATENCY)
        assert s[1].stamp < front_passes(train, LAYOUT.air2[1])               # B before the air section
    # the detection events against the truth: the axle counter sees the last axle at AC1 within a block
    t_rear = rear_passes(train, LAYOUT.ac[1])
    assert t_rear <= t_ac <= t_rear + BLOCK + 0.01
    # the track circuit picks up half a tuned zone (12 m) later, after its pick-up delay (0.5 s)
    assert t_tc == pytest.approx(rear_passes(train, LAYOUT.ac[1] + direction * 12.0) + 0.5, abs=BLOCK + 0.02)
    assert r.short_circuits == [] and r.air_switchings == [] and r.safe_entries == []
    assert r.controller_status["mode"] == "IDLE" and r.controller_status["feed"] == "A"
    p = r.passages[0]
    assert p.dead_time == pytest.approx(s[3].stamp - s[2].stamp if direction < 0 else s[1].stamp - s[0].stamp,
                                        abs=0.01)
    assert p.crossing_time == pytest.approx(1000.0 / kmh(200.0), rel=1e-6)
    assert p.unfed_time == pytest.approx(p.crossing_time, abs=0.01)


@pytest.mark.parametrize("direction,kind", [(1, "front-pantograph-400"), (-1, "EMU-320x2")])
def test_no_bridging_and_no_air_section_switching_at_330_kmh(direction, kind):
    train, r = sim(direction=direction, speed_kmh=330.0, kind=kind, seed=5)
    assert r.short_circuits == [] and r.air_switchings == [] and r.safe_entries == []
    # dead time well under a second against 11 s to cross the neutral section
    p = r.passages[0]
    assert 0.0 < p.dead_time < 1.0 and p.crossing_time == pytest.approx(1000.0 / kmh(330.0), rel=1e-6)


def test_following_train_is_held_then_fed_without_bridging():
    span = LAYOUT.ac[2] - LAYOUT.ac[0]

    def make():
        lead = TrainSpec.of_type("KTX", name="lead", direction=1, entry_time=30.0, speed=kmh(250.0))
        # the follower's front at AC0 1 s before the leader's last axle has left S2 at AC2
        follow = TrainSpec.of_type("EMU-320", name="follow", direction=1,
                                   entry_time=lead.time_at(span + max(lead.axles)) - 1.0, speed=kmh(300.0))
        return Run([lead, follow], seed=3)
    run, r = cached("follow", make)
    follow = run.trains[1]
    assert r.short_circuits == [] and r.air_switchings == []
    assert [why for _, why in r.safe_entries if "following train" in why]
    assert switch_sequence(r) == [(ABB1, False), (ABB2, True), (ABB2, False), (ABB1, True)] * 2
    # the follower entered while the leader's S2 was still occupied: the feed came back to A
    # before the follower reached air section 1
    assert r.switchings[3].stamp < front_passes(follow, LAYOUT.air1[0])
    assert all(p.dead_time < 1.0 for p in r.passages)


# ---------------------------------------------------------------- injected faults

@pytest.mark.parametrize("layout", ["seed", "blocks"])
def test_poor_shunt_train_is_held_by_the_axle_counter(layout):
    """The track circuits do not see the train (seed 004 4.2: the dangerous side of a track
    circuit); the axle counter keeps the sections occupied and nothing bridges. Over the
    whole blocks (``blocks``) the lasting disagreement puts the changeover in its safe state
    (neutral dead). On the seed's layout the 400 m circuits cover part of each block, so the
    axle counter alone is no contradiction there: the middle changeover opens ABB-1 as the
    front reaches AC1 (the track circuit's CLEAR is the first sign) and closes ABB-2 when the
    last axle has passed it (both systems clear): dead for the train's length."""
    train, r = sim(direction=1, speed_kmh=120.0, seed=2, train={"poor_shunt": True},
                   track_circuit={"poor_shunt_resistance": 1.0e4}, layout=dict(LAYOUTS[layout]))
    log = r.occupancy_log
    assert all(states["S1"][1] == CLEAR and states["S2"][1] == CLEAR for _, states in log)   # TC sees nothing
    t_in = first_change(log, "S1", 0, OCCUPIED)
    assert front_passes(train, LAYOUT.ac[0]) <= t_in <= front_passes(train, LAYOUT.ac[0]) + BLOCK + 0.01
    t_out = first_change(log, "S1", 0, CLEAR, after=t_in)
    assert rear_passes(train, LAYOUT.ac[1]) <= t_out <= rear_passes(train, LAYOUT.ac[1]) + BLOCK + 0.01
    assert r.short_circuits == [] and r.air_switchings == []
    if layout == "seed":
        assert r.safe_entries == [] and r.contradictions == []
        assert switch_sequence(r) == [(ABB1, False), (ABB2, True), (ABB2, False), (ABB1, True)]
        front = front_passes(train, LAYOUT.ac[1])
        # S2 occupied, then (the next block) S1's first clear: two blocks at most
        assert front <= r.switchings[0].stamp <= front + 2 * BLOCK + LATENCY + HALF_CYCLE + 0.01
        assert r.switchings[1].stamp == pytest.approx(t_out + LATENCY, abs=0.01)
        assert r.passages[0].dead_time == pytest.approx(r.switchings[1].stamp - r.switchings[0].stamp, abs=0.01)
        assert r.passages[0].dead_time > 10.0                     # 388 m at 120 km/h
        return
    assert r.safe_entries and "S1 contradictory: track circuit CLEAR, axle counter OCCUPIED" in r.safe_entries[0][1]
    assert r.safe_entries[0][0] == pytest.approx(t_in + 3.0, abs=BLOCK + 0.01)
    # safe state: the neutral dead until both systems have seen every section clear for 5 s
    assert switch_sequence(r) == [(ABB1, False), (ABB1, True)]
    assert r.switchings[1].stamp > rear_passes(train, LAYOUT.ac[2]) + 5.0
    assert r.passages[0].dead_time == pytest.approx(r.passages[0].unfed_time, abs=0.01)
    assert r.controller_status["mode"] == "IDLE"


def test_weak_poor_shunt_releases_the_track_circuit_early_and_the_axle_counter_holds_it():
    """20 Ohm per axle: the track circuit drops late and releases S1 before the last axle has
    left; ABB-2 closes only when the axle counter has counted the last axle out."""
    train, r = sim(direction=1, speed_kmh=300.0, seed=2, train={"poor_shunt": True})
    log = r.occupancy_log
    t_rear = rear_passes(train, LAYOUT.ac[1])
    t_tc = first_change(log, "S1", 1, CLEAR, after=first_change(log, "S2", 0, OCCUPIED))
    assert t_tc < t_rear                                       # the track circuit alone would release too early
    on_b = [s.stamp for s in r.switchings if s.switch == ABB2 and s.on]
    assert on_b and on_b[0] >= t_rear
    assert r.short_circuits == [] and r.air_switchings == []


@pytest.mark.parametrize("circuit", ["TC1", "TC2"])
def test_track_circuit_stuck_occupied_leads_to_the_safe_state(circuit):
    """TC stuck OCCUPIED (transmitter failed) while the train is in its section: the axle
    counter sees the section clear, the changeover opens ABB-1 at the first clear and never
    closes B on a contradictory section: safe state, no bridging."""
    train = TrainSpec.of_type("KTX", name="t1", direction=1, entry_time=30.0, speed=kmh(250.0))
    t_fault = front_passes(train, LAYOUT.ac[1]) if circuit == "TC2" else 31.0
    _, r = sim(direction=1, speed_kmh=250.0, seed=4, track_circuit={"faults": f"{circuit}@{t_fault:.2f}:tx_failed"})
    section = "S1" if circuit == "TC1" else "S2"
    assert r.short_circuits == []
    assert r.controller_status["mode"] == "SAFE" and r.controller_status["feed"] == "OFF"
    assert any(f"{section} contradictory: track circuit OCCUPIED, axle counter CLEAR" in why
               for _, why in r.safe_entries)
    # the axle counter saw the train leave the section (the other system's correct detection)
    t_rear = rear_passes(train, LAYOUT.ac[1] if section == "S1" else LAYOUT.ac[2])
    assert t_rear <= first_change(r.occupancy_log, section, 2, CLEAR, after=t_rear - 1.0) <= t_rear + BLOCK + 0.01
    if section == "S1":
        assert not any(s.on for s in r.switchings)             # B never closed on a contradictory S1


def test_axle_counter_disturbed_leads_to_the_safe_state_and_the_track_circuit_detects():
    """A spurious axle at AC1 (leaving S1 with nobody in it) drives S1 negative: DISTURBED.
    The changeover goes safe before the train comes; the track circuit still shows the train."""
    train, r = sim(direction=-1, speed_kmh=160.0, seed=6, axle_counter={"faults": "AC1@27.0:extra"})
    assert r.safe_entries[0][0] == pytest.approx(27.0, abs=0.2)
    assert "S1 DISTURBED: track circuit CLEAR, axle counter DISTURBED" in r.safe_entries[0][1]
    assert switch_sequence(r) == [(ABB1, False)]               # dead neutral, nothing closes again
    assert r.short_circuits == [] and r.air_switchings == []
    t_s1 = first_change(r.occupancy_log, "S1", 1, OCCUPIED)
    assert front_passes(train, LAYOUT.ac[1] + 12.0) <= t_s1 <= front_passes(train, LAYOUT.ac[1]) + 0.3
    assert first_change(r.occupancy_log, "S1", 0, OCCUPIED) == t_s1   # voted occupied (degraded)


def test_missed_axle_makes_the_next_section_disturbed_and_the_changeover_safe():
    train, r = sim(direction=1, speed_kmh=200.0, seed=7, train={"ac_faults": "AC0@0.0:missed"})
    # AC0 missed the first axle: S1 goes negative when the last one leaves it at AC1
    t_rear = rear_passes(train, LAYOUT.ac[1])
    assert len(r.safe_entries) == 1
    assert r.safe_entries[0][0] == pytest.approx(t_rear, abs=BLOCK + 0.01)
    assert r.safe_entries[0][1] == "S1 degraded: track circuit OCCUPIED, axle counter DISTURBED"
    assert first_change(r.occupancy_log, "S1", 0, DISTURBED) > t_rear     # after the track circuit released
    assert r.controller_status["mode"] == "SAFE"
    assert r.short_circuits == [] and r.air_switchings == []


def test_silent_axle_counter_keeps_the_changeover_safe():
    _, r = sim(direction=1, speed_kmh=250.0, seed=8, drop=("axle_counter",))
    assert r.safe_entries and "SILENT" in r.safe_entries[0][1]
    assert r.controller_status["mode"] == "SAFE"
    assert r.short_circuits == [] and not any(s.on for s in r.switchings)


# ---------------------------------------------------------------- the controller alone

def section(sid, state, tc=None, ac=None, contradiction=False):
    tc = state if tc is None else tc
    ac = state if ac is None else ac
    return CombinedSection(sid, 0.0, 1.0, state, tc, ac, tc != ac, contradiction, False)


def drive(ctrl, steps):
    out = []
    for now, (w, e) in steps:
        out += [(round(c.stamp, 3), c.switch, c.on) for c in ctrl.update(now, [section("S1", *w), section("S2", *e)])]
    return out


def test_controller_refuses_an_occupancy_no_train_makes_and_recovers():
    ctrl = ChangeoverController()
    cmds = drive(ctrl, [(0.0, ((OCCUPIED,), (OCCUPIED,))), (1.0, ((CLEAR,), (CLEAR,))), (5.9, ((CLEAR,), (CLEAR,))),
                        (6.0, ((CLEAR,), (CLEAR,)))])
    assert ctrl.safe_entries == [(0.0, "S1 and S2 occupied at once with no train entering")]
    assert cmds == [(0.0, ABB1, False), (6.0, ABB1, True)]     # recovered after recover_time (5 s)
    assert ctrl.mode == "IDLE"


def test_controller_goes_safe_when_a_section_is_reoccupied_during_the_changeover():
    ctrl = ChangeoverController()
    drive(ctrl, [(0.0, ((OCCUPIED,), (CLEAR,))), (1.0, ((OCCUPIED,), (OCCUPIED,))),
                 (2.0, ((OCCUPIED, OCCUPIED, CLEAR), (OCCUPIED,))), (2.5, ((OCCUPIED,), (OCCUPIED,)))])
    assert ctrl.safe and "S1 occupied again during the changeover" in ctrl.reason


# ---------------------------------------------------------------- cross-check

def occupancy(states):
    return SectionOccupancy(0.0, "combined", tuple(SectionState(sid, a, b, st, 0, 0, 0)
                                                   for sid, (a, b, st) in states.items()))


def test_crosscheck_flags_a_train_where_the_line_sees_nobody_and_the_reverse():
    x0, x1, x2 = LAYOUT.ac
    check = CrossCheck()
    persist = check.params["persist"]
    # the train says its front is 300 m into S2, the line sees it in S1
    wrong = Claim("t1", 0.0, x1 + 295.0, x1 + 305.0, 200.0, 1, 10.0)
    occ = occupancy({"S1": (x0, x1, OCCUPIED), "S2": (x1, x2, CLEAR)})
    assert check.update(0.0, [wrong], occ) == []
    flags = check.update(persist, [wrong], occ)
    assert sorted((f.kind, f.section_id, f.train) for f in flags) == [("claims_clear", "S2", "t1"),
                                                                      ("unclaimed", "S1", "")]
    # where the line sees it: nothing to flag, the flags end
    right = Claim("t1", 0.0, x1 - 105.0, x1 - 95.0, 200.0, 1, 10.0)
    assert check.update(persist + 1.0, [right], occ) == []
    assert all(f.end == persist + 1.0 for f in check.records)
    # a train astride the boundary within the wayside's lag is no contradiction
    astride = Claim("t1", 0.0, x1 + 40.0, x1 + 50.0, 200.0, 1, 30.0)
    assert check.update(persist + 2.0, [astride], occ) == [] and check.update(2 * persist + 3.0, [astride], occ) == []
    # a train without a position claims nothing surely and may be anywhere
    lost = Claim("t1", 0.0, -math.inf, math.inf, 200.0, 1, 0.0, valid=False)
    assert check.update(3 * persist + 4.0, [lost], occ) == [] and check.update(4 * persist + 5.0, [lost], occ) == []


def test_crosscheck_on_a_simulated_passage_flags_the_wrong_claim_only():
    train, r = sim(direction=-1)
    sections = {"S1": (LAYOUT.ac[0], LAYOUT.ac[1]), "S2": (LAYOUT.ac[1], LAYOUT.ac[2])}
    log = r.occupancy_log

    def run_check(offset):
        check = CrossCheck()
        for now in np.arange(log[0][0], log[-1][0] + 10.0, 0.25):
            states = [st for stamp, st in log if stamp <= now][-1]
            occ = to_occupancy(now, [section(sid, st[0]) for sid, st in states.items()])
            occ = SectionOccupancy(now, "combined", tuple(SectionState(s.section_id, *sections[s.section_id],
                                                                       s.state, 0, 0, 0) for s in occ.sections))
            front = LAYOUT.ac[2] - float(train.distance(now - train.entry_time)) - offset
            check.update(now, [Claim("t1", now, front - 2.0, front + 2.0, train.length, -1, train.speed)], occ)
        return check.records

    assert run_check(0.0) == []                                  # the truth: no flag
    wrong = run_check(600.0)                                     # claims to be 600 m further on
    assert {(f.kind, f.section_id) for f in wrong} >= {("claims_clear", "S1"), ("unclaimed", "S2")}


# ---------------------------------------------------------------- campaign

def test_campaign_draws_both_directions_speeds_in_range_and_close_following():
    runs = generate(60, seed=0)
    trains = [t for run in runs for t in run.trains]
    assert len(trains) == 60
    assert {t.direction for t in trains} == {1, -1}
    speeds = np.array([t.speed for t in trains] + [t.final_speed for t in trains if t.final_speed]) * 3.6
    assert speeds.min() >= 30.0 - 1e-9 and speeds.max() <= 330.0 + 1e-9
    span = LAYOUT.ac[2] - LAYOUT.ac[0]
    gaps = [b.entry_time - a.time_at(span + a.length) for run in runs for a, b in zip(run.trains, run.trains[1:])]
    assert min(gaps) >= 0.0 and min(gaps) < 3.0
    faulty = generate(20, seed=1, faults=True)
    assert any(run.label for run in faulty) and len([t for run in faulty for t in run.trains]) == 20


def test_summary_counts_the_events_of_the_runs():
    sim()                                       # at least one run, whatever ran before
    runs, results = zip(*_RUNS.values())
    s = summarise(list(runs), list(results))
    assert s["passages"] == sum(len(r.passages) for r in results)
    assert s["nominal"]["short_circuits"] + s["faulty"]["short_circuits"] == sum(len(r.short_circuits)
                                                                                for r in results)
    assert s["dead_time_s"]["max"] == max(p.dead_time for r in results for p in r.passages)


# ---------------------------------------------------------------- nodes (in process)

def test_nodes_vote_publish_and_go_safe_on_a_disturbed_axle_counter(ros_context):
    import time as _time

    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.executors import SingleThreadedExecutor
    from std_msgs.msg import Bool

    from train_localization.core import convert
    from train_localization.nodes.common import LATCHED_QOS, rclpy_classes
    from train_localization.nodes.wayside import ChangeoverControllerNode, WaysideOccupancyNode

    from rclpy.parameter import Parameter
    mc = rclpy_classes()
    ctrl = ChangeoverControllerNode(parameter_overrides=[Parameter("recover_time", value=0.5)])
    vote_node = WaysideOccupancyNode()
    probe = ros_context.create_node("probe_wayside")
    pub = probe.create_publisher(mc.SectionOccupancy, convert.SECTIONS_TOPIC, LATCHED_QOS)
    abb1, combined, diags = [], [], []
    probe.create_subscription(Bool, "changeover/abb1", lambda m: abb1.append(m.data), LATCHED_QOS)
    probe.create_subscription(mc.SectionOccupancy, "wayside/combined", combined.append, LATCHED_QOS)
    probe.create_subscription(DiagnosticArray, "/diagnostics", diags.append, 10)
    ex = SingleThreadedExecutor()
    for n in (ctrl, vote_node, probe):
        ex.add_node(n)

    def spin(seconds, until=lambda: False):
        end = _time.monotonic() + seconds
        while _time.monotonic() < end and not until():
            ex.spin_once(timeout_sec=0.05)

    def send(tc, ac):
        now = _time.time()
        pub.publish(convert.measurement_to_msg(report(now, "track_circuit", {"TC1": tc[0], "TC2": tc[1]}), mc))
        pub.publish(convert.measurement_to_msg(report(now, "axle_counter", {"S1": ac[0], "S2": ac[1]}), mc))

    def status(name):
        for arr in reversed(diags):
            for st in arr.status:
                if name in st.name:
                    return st
        return None
    try:
        spin(10.0, lambda: pub.get_subscription_count() >= 2)
        # no report yet: both systems silent, the safe state (ABB-1 opened after its initial state)
        spin(3.0, lambda: status("changeover") is not None and "SILENT" in status("changeover").message)
        assert abb1[:2] == [True, False]
        send((CLEAR, CLEAR), (CLEAR, CLEAR))
        spin(1.0)
        send((CLEAR, CLEAR), (CLEAR, CLEAR))
        spin(2.0, lambda: abb1[-1] is True)
        assert abb1 == [True, False, True]                     # recovered: idle, the neutral fed from A
        send((CLEAR, CLEAR), (DISTURBED, CLEAR))
        spin(4.0, lambda: abb1[-1] is False and status("changeover") is not None
             and "SAFE" in status("changeover").message)
        assert abb1[-1] is False
        st = status("changeover")
        assert st.level == bytes([2]) and "S1 DISTURBED: track circuit CLEAR, axle counter DISTURBED" in st.message
        assert combined and [s.state for s in combined[-1].sections] == [DISTURBED, CLEAR]
        # the voting node reports on its own diagnostics period: wait for its report of the change
        spin(3.0, lambda: status("combined wayside detection") is not None
             and status("combined wayside detection").level == bytes([2]))
        assert status("combined wayside detection").level == bytes([2])
    finally:
        for n in (ctrl, vote_node, probe):
            ex.remove_node(n)
            n.destroy_node()


def test_crosscheck_node_flags_a_train_claiming_a_clear_section(ros_context):
    import time as _time

    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter

    from train_localization.core import convert
    from train_localization.nodes.common import LATCHED_QOS, STATE_QOS, rclpy_classes
    from train_localization.nodes.wayside import CrossCheckNode

    mc = rclpy_classes()
    node = CrossCheckNode(parameter_overrides=[Parameter("persist", value=0.2), Parameter("train_length", value=200.0)])
    probe = ros_context.create_node("probe_crosscheck")
    state_pub = probe.create_publisher(mc.TrainState, "localization/state", STATE_QOS)
    occ_pub = probe.create_publisher(mc.SectionOccupancy, "wayside/combined", LATCHED_QOS)
    diags = []
    probe.create_subscription(DiagnosticArray, "/diagnostics", diags.append, 10)
    ex = SingleThreadedExecutor()
    for n in (node, probe):
        ex.add_node(n)

    def message():
        for arr in reversed(diags):
            for st in arr.status:
                if "cross-check" in st.name:
                    return st.level, st.message
        return None
    try:
        end = _time.monotonic() + 10.0
        while _time.monotonic() < end and not (state_pub.get_subscription_count() and occ_pub.get_subscription_count()):
            ex.spin_once(timeout_sec=0.05)
        x0, x1, x2 = LAYOUT.ac
        now = _time.time()
        state = convert.train_state_to_msg(mc, now, "changeover", x1 + 300.0, 20.0, 0.0, 1.0, 0.1, x1 + 297.0,
                                           x1 + 303.0, 0.999, 1, [])
        occ = SectionOccupancy(now, "combined", (SectionState("S1", x0, x1, OCCUPIED, 0, 0, 0),
                                                 SectionState("S2", x1, x2, CLEAR, 0, 0, 0)))
        state_pub.publish(state)
        occ_pub.publish(convert.measurement_to_msg(occ, mc))
        end = _time.monotonic() + 5.0
        while _time.monotonic() < end and not (message() and "claims section S2" in message()[1]):
            ex.spin_once(timeout_sec=0.05)
        level, text = message()
        assert level == bytes([1]) and "train claims section S2, which the wayside reports clear" in text
        assert "section S1 is occupied and no train claims it" in text
    finally:
        for n in (node, probe):
            ex.remove_node(n)
            n.destroy_node()


@pytest.mark.parametrize("direction", [1, -1])
def test_the_seeds_moments_per_direction_switch_at_the_middle_with_no_bridge(direction):
    """Seed 004 section 4.1 per running direction (SeedMomentsController) on the seed's layout
    (section 4.2: 400 m track circuits in a 1 km neutral section, 800 m blocks): the neutral
    goes from the phase behind the train to the phase ahead when its front enters the circuit
    it enters second, at AC1; the dead time is the gap only (0.09 s); no short circuit and no
    switching under a pantograph, for the KTX (pantograph 373 m behind the front) and the
    coupled EMU-320 (360 m). The staged controller on the same passage: no bridge either, a
    dead time of 0.74 s (last axle past AC1 until the track circuit has picked up)."""
    assert LAYOUT.tc1 == (1400.0, 1800.0) and LAYOUT.tc2 == (1800.0, 2200.0)
    assert LAYOUT.air1[1] < LAYOUT.tc1[0] and LAYOUT.tc2[1] < LAYOUT.air2[0]
    assert LAYOUT.params["neutral_length"] == 1000.0 and LAYOUT.ac[1] - LAYOUT.ac[0] == 800.0
    for kind in ("KTX", "EMU-320x2"):
        train, seed = sim(direction=direction, kind=kind, controller_kind="seed")
        assert seed.short_circuits == [] and seed.air_switchings == [] and seed.safe_entries == []
        assert switch_sequence(seed) == [(ABB1, False), (ABB2, True), (ABB2, False), (ABB1, True)]
        s = seed.switchings
        middle = s[0] if direction > 0 else s[2]                 # A -> B: the first pair; B -> A: the second
        front = front_passes(train, LAYOUT.ac[1])
        assert front <= middle.stamp <= front + BLOCK + LATENCY + HALF_CYCLE + 0.01
        if direction < 0:                                        # B fed before the air section
            assert s[1].stamp < front_passes(train, LAYOUT.air2[1])
        assert seed.passages[0].dead_time == pytest.approx(GAP - HALF_CYCLE, abs=0.005)
        _, ours = sim(direction=direction, kind=kind)
        assert ours.short_circuits == [] and ours.air_switchings == []
        assert ours.passages[0].dead_time > 0.5


@pytest.mark.parametrize("direction", [1, -1])
@pytest.mark.parametrize("pantograph, bridged_by", [(560.0, "seed"), (40.0, "staged")])
def test_each_controller_bridges_the_phases_on_a_train_too_long_for_its_moment(direction, pantograph, bridged_by):
    """The trade (docs/changeover.md), on a 600 m train with one raised pantograph. The seed's
    moment (the front at AC1) is safe while the pantograph is then past the first air section:
    less than half the neutral section (500 m) behind the first axle. The staged one (the last
    axle past AC1) is safe while the pantograph has not yet reached the second air section
    then: less than 500 m ahead of the last axle. 560 m behind the front breaks the first,
    40 m behind it the second; the other controller passes the same train cleanly."""
    def run(controller):
        def make():
            t = TrainSpec(name="t1", direction=direction, entry_time=30.0, speed=kmh(200.0), length=600.0,
                          pantographs=(pantograph,), kind="600 m")
            return Run([t], seed=1, controller_kind=controller)
        return cached(("600 m", pantograph, direction, controller), make)[1]
    for controller in ("seed", "staged"):
        r = run(controller)
        if controller == bridged_by:
            assert len(r.short_circuits) == 1 and r.short_circuits[0]["cause"] == "pantograph bridge: t1"
        else:
            assert r.short_circuits == [] and r.air_switchings == [] and r.safe_entries == []
