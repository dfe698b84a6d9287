"""AF jointless track circuits UM71C / TI21 (seed 004 sections 3.1, 3.2, Tables 1-2, 4.2):
carrier allocation, the rails as a transmission line, occupancy with its delays, faults."""

import dataclasses
import math

import numpy as np
import pytest
import yaml

from conftest import ROOT
from error_model_checks import assert_forged_fixes_refused
from train_localization.core.measurements import CLEAR, DISTURBED, OCCUPIED, PositionFix, SectionOccupancy
from train_localization.core.pipeline import SensorPipeline, run_offline, simulate_and_decode
from train_localization.core.scenario import Scenario, Vehicle
from train_localization.core.sensors import NODE_NAMES, spec
from train_localization.core.sensors import track_circuit as tc
from train_localization.core.sensors.base import resolve_params
from train_localization.core.signals import InputRejected, RawBlock
from train_localization.core.track import Track, TrackError

NODE = "track_circuit_receiver"
V300 = 300.0 / 3.6
CAR = 25.0
FIRST_AXLE = 3.0
PARAMS = resolve_params(tc.PARAMS, {})
UM71C = [{"every": 1500.0, "start": 0.0, "end": 4500.0, "id": "TC{n:02d}", "length": 1500.0, "system": "UM71C",
          "line": "T1"}]                                  # TC00..TC03, 0 .. 6000 m
TI21 = [{"every": 800.0, "start": 1000.0, "end": 3400.0, "id": "TI{n:02d}", "length": 800.0, "system": "TI21",
         "pair": "A/B"}]                                  # TI00..TI03, 1000 .. 4200 m


def axles(cars=8):
    """4 axles per 25 m car: bogies 17.5 m apart, 2.5 m wheelbase."""
    return [a + CAR * k for k in range(cars) for a in (FIRST_AXLE, 5.5, 20.5, 23.0)]


def track(circuits, length=7000.0):
    return Track.from_dict({"track_id": "T", "length": length, "equipment": {"track_circuit": circuits}})


def scenario(circuits=UM71C, speed=V300, start=300.0, duration=80.0, params=None, vehicle_axles=None, length=7000.0):
    vehicle_axles = axles() if vehicle_axles is None else vehicle_axles
    return Scenario.from_dict({
        "name": "track_circuit", "seed": 2, "duration": duration,
        "track": {"track_id": "T", "length": length, "equipment": {"track_circuit": circuits}},
        "vehicle": {"type": "emu", "length": max(vehicle_axles) + 2.0, "axles": vehicle_axles},
        "initial": {"position": start, "speed": speed},
        "profile": [{"speed": speed, "hold": 1000.0}],
        "sensors": {NODE: {"first_axle_offset": FIRST_AXLE, "block_duration": 0.2, **(params or {})}},
    })


def transitions(ms):
    """{circuit id: [(stamp, state) at each change]} from the occupancy reports."""
    out, last = {}, {}
    for m in ms:
        if isinstance(m, SectionOccupancy):
            for s in m.sections:
                if last.get(s.section_id) != s.state:
                    out.setdefault(s.section_id, []).append((m.stamp, s.state))
                    last[s.section_id] = s.state
    return out


def axle_span_times(sc, circuit, dt=0.001, orientation=1):
    """(first, last) time an axle of the train is on the circuit's rails (zones included);
    orientation -1: the train's front faces decreasing chainage."""
    traj = sc.trajectory()
    t = np.arange(0.0, sc.duration, dt)
    front = np.interp(t, traj.t, traj.position)
    x = front[:, None] - orientation * np.asarray(sc.vehicle.axles)[None, :]
    half = 0.5 * circuit["zone"]
    inside = ((x > circuit["start"] - half) & (x < circuit["end"] + half)).any(axis=1)
    idx = np.flatnonzero(inside)
    return (t[idx[0]], t[idx[-1]]) if idx.size else (None, None)


def level(circuit, ballast, shunts=()):
    """Receiver level [1] (adjusted to 1 at adjust_ballast) with axle shunts [(chainage, ohm)]."""
    ref = abs(tc.CircuitLine(circuit, PARAMS, PARAMS["adjust_ballast"]).empty[0][0])
    line = tc.CircuitLine(circuit, PARAMS, ballast)
    if not shunts:
        return abs(line.empty[0][0]) / ref
    x = np.array([[s[0] for s in sorted(shunts)]])
    r = np.array([[s[1] for s in sorted(shunts)]])
    return abs(line.voltages(x, r)[0][0]) / ref


def worst_level(circuit, ballast, resistance, step=5.0):
    """Highest level with one shunt anywhere on the circuit's rails (zones included)."""
    half = 0.5 * circuit["zone"]
    xs = np.arange(circuit["start"] - half + 0.01, circuit["end"] + half, step)
    line = tc.CircuitLine(circuit, PARAMS, ballast)
    ref = abs(tc.CircuitLine(circuit, PARAMS, PARAMS["adjust_ballast"]).empty[0][0])
    v, _ = line.voltages(xs[:, None], np.full((xs.size, 1), resistance))
    return float(np.max(np.abs(v))) / ref


# -- carrier allocation (seed 004 Tables 1 and 2, section 4.2) --------------------------

@pytest.mark.parametrize("line,pair", [("T1", (2040.0, 2760.0)), ("T2", (2400.0, 3120.0))])
def test_um71c_carriers_alternate_on_each_track_as_table_1(line, pair):
    circuits = tc.circuit_table(track([dict(UM71C[0], line=line)]), PARAMS)
    assert [c["carrier"] for c in circuits] == [pair[0], pair[1], pair[0], pair[1]]
    assert [c["label"] for c in circuits] == ["F1", "F2", "F1", "F2"]
    # neighbours touch (jointless) and differ; every circuit about 1,500 m (section 3.1)
    assert all(c["end"] - c["start"] == pytest.approx(tc.UM71C_LENGTH) for c in circuits)
    assert [(c["below"], c["above"]) for c in circuits] == [(-1, 1), (0, 2), (1, 3), (2, -1)]


def test_compensating_capacitors_every_60_m_at_2040_2400_and_80_m_at_2760_3120():
    for line in ("T1", "T2"):
        for c in tc.circuit_table(track([dict(UM71C[0], line=line)]), PARAMS):
            spacing = 60.0 if c["carrier"] in (2040.0, 2400.0) else 80.0
            assert c["spacing"] == spacing
            caps = tc.CircuitLine(c, PARAMS, 5.0).bounds[1:-1]
            assert np.allclose(np.diff(caps), spacing)
            assert len(caps) == math.ceil(1500.0 / spacing)
    # compensation raises the received level (section 4.2: better transmission level)
    c = tc.circuit_table(track(UM71C), PARAMS)[1]
    bare = dict(PARAMS, capacitor=0.0)
    ref = abs(tc.CircuitLine(c, PARAMS, 5.0).empty[0][0])
    assert ref > 2.0 * abs(tc.CircuitLine(c, bare, 5.0).empty[0][0])


def test_ti21_frequencies_are_table_2_and_a_b_alternate():
    table2 = {"A": (1699, 1682, 1716), "B": (2296, 2279, 2313), "C": (1996, 1979, 2013), "D": (2593, 2576, 2610),
              "E": (1549, 1532, 1566), "F": (2146, 2129, 2163), "G": (1848, 1831, 1865), "H": (2445, 2428, 2462)}
    assert tc.TI21_FREQUENCIES == {k: tuple(float(f) for f in v) for k, v in table2.items()}
    for letter, (nominal, low, high) in table2.items():
        assert (low, high) == (nominal - 17, nominal + 17)
    bands = [f for v in table2.values() for f in v[1:]]
    assert (min(bands), max(bands)) == (1532, 2610)
    for pair, letters in (("A/B", "AB"), ("C/D", "CD"), ("E/F", "EF"), ("G/H", "GH")):
        circuits = tc.circuit_table(track([dict(TI21[0], pair=pair)]), PARAMS)
        assert [c["label"] for c in circuits] == [letters[0], letters[1]] * 2
        assert [c["carrier"] for c in circuits] == [table2[letters[k % 2]][0] for k in range(4)]
        assert circuits[0]["band"] == table2[letters[0]][1:]
        assert all(c["zone"] == 20.0 and c["spacing"] == 0.0 for c in circuits)   # section 3.2


@pytest.mark.parametrize("entries,why", [
    ([{"id": "A", "start": 0.0, "end": 1500.0, "carrier": 2040.0},
      {"id": "B", "start": 1500.0, "end": 3000.0, "carrier": 2040.0}], "same carrier"),
    ([{"id": "A", "start": 0.0, "end": 1500.0, "line": "T1", "carrier": 2400.0}], "not one of track T1"),
    ([{"id": "A", "start": 0.0, "end": 800.0, "system": "TI21", "pair": "A/B", "carrier": "C"}], "not of pair"),
    ([{"id": "A", "start": 0.0, "end": 900.0}, {"id": "B", "start": 800.0, "end": 1500.0}], "overlaps"),
    ([{"id": "A", "start": 0.0, "end": 900.0, "system": "TVM"}], "system"),
])
def test_a_table_that_cannot_be_laid_is_refused(entries, why):
    with pytest.raises(TrackError, match=why):
        tc.circuit_table(track(entries), PARAMS)


def test_the_config_line_has_ten_um71c_circuits_of_1500_m():
    tr = Track.from_dict(yaml.safe_load((ROOT / "config" / "track_highspeed.yaml").read_text()))
    circuits = tc.circuit_table(tr, PARAMS)
    assert len(circuits) == 10
    assert all(c["end"] - c["start"] == 1500.0 and c["system"] == "UM71C" for c in circuits)
    assert [c["carrier"] for c in circuits] == [2040.0, 2760.0] * 5


# -- transmission line ------------------------------------------------------------------

CIRCUITS = {"UM71C 2040 Hz": tc.circuit_table(track(UM71C), PARAMS)[0],
            "UM71C 3120 Hz": tc.circuit_table(track([dict(UM71C[0], line="T2")]), PARAMS)[1],
            "TI21 A 1000 m": tc.circuit_table(track([{"id": "X", "start": 0.0, "end": 1000.0, "system": "TI21"}]),
                                              PARAMS)[0],
            "TI21 D 1000 m": tc.circuit_table(track([{"id": "X", "start": 0.0, "end": 1000.0, "system": "TI21",
                                                      "pair": "C/D", "carrier": "D"}]), PARAMS)[0]}
# critical shunt at the worst position [Ohm]: the documented range (module docstring)
CRITICAL = {2.0: (0.5, 1.0), 20.0: (0.15, 0.4)}


@pytest.mark.parametrize("name", list(CIRCUITS))
@pytest.mark.parametrize("ballast", [2.0, 20.0])
def test_receiver_level_clear_above_and_test_shunt_anywhere_below_the_threshold(name, ballast):
    c = CIRCUITS[name]
    clear = level(c, ballast)
    assert clear > PARAMS["threshold_pick"] * 1.5
    if ballast == PARAMS["adjust_ballast"]:
        assert clear == pytest.approx(1.0)
    # 0.06 Ohm anywhere on the rails, tuned zones included
    assert worst_level(c, ballast, 0.06) < 0.5 * PARAMS["threshold_drop"]
    # an axle just off the circuit's rails (beyond the tuned zone) does not shunt it
    half = 0.5 * c["zone"]
    assert level(c, ballast, [(c["start"] - half - 1.0, 0.06)]) == pytest.approx(clear)
    assert level(c, ballast, [(c["end"] + half + 1.0, 0.06)]) == pytest.approx(clear)


@pytest.mark.parametrize("name", list(CIRCUITS))
@pytest.mark.parametrize("ballast", [2.0, 20.0])
def test_critical_shunt_resistance_lies_in_the_documented_range(name, ballast):
    c = CIRCUITS[name]
    lo, hi = 1e-3, 100.0
    for _ in range(30):                    # bisection (geometric) on the worst level = drop threshold
        mid = math.sqrt(lo * hi)
        lo, hi = (mid, hi) if worst_level(c, ballast, mid, step=10.0) < PARAMS["threshold_drop"] else (lo, mid)
    assert CRITICAL[ballast][0] < lo < CRITICAL[ballast][1], (name, ballast, lo)
    # dry ballast (little leakage) is the worst case for shunting (higher clear level)
    assert level(c, 20.0) > level(c, 2.0)


def test_axles_in_parallel_shunt_better_than_one():
    c = CIRCUITS["UM71C 2040 Hz"]
    x = c["end"] - 2.0
    one = level(c, 20.0, [(x, 0.5)])
    bogie = level(c, 20.0, [(x - 2.5, 0.5), (x, 0.5)])
    assert bogie < one < level(c, 20.0)


# -- simulated passages -------------------------------------------------------------------

@pytest.mark.parametrize("circuits,speed,start", [(UM71C, V300, 300.0), (TI21, -40.0, 4400.0)],
                         ids=["UM71C-300kmh", "TI21-backwards"])
def test_passage_every_circuit_occupied_while_an_axle_is_in_it_then_clear_with_the_delays(circuits, speed, start):
    sign = 1 if speed > 0 else -1
    params = {"orientation": sign}
    sc = scenario(circuits, speed=speed, start=start, duration=80.0 if speed > 0 else 95.0, params=params)
    blocks, ms, pipe = run_offline(NODE, sc)
    for m in ms:
        m.validate()
    table = tc.circuit_table(sc.track, pipe.params)
    trans = transitions(ms)
    dt = 1.0 / pipe.sample_rate
    for c in table:
        t_in, t_out = axle_span_times(sc, c, orientation=sign)
        states = trans[c["id"]]
        if t_in == 0.0:     # the train starts on it
            assert states[0][1] == CLEAR and states[1] == pytest.approx((PARAMS["drop_delay"], OCCUPIED), abs=dt)
        else:
            assert [s for _, s in states] == [CLEAR, OCCUPIED, CLEAR], (c["id"], states)
            assert states[1][0] == pytest.approx(t_in + PARAMS["drop_delay"], abs=dt + 1e-6), c["id"]
        assert states[-1][1] == CLEAR
        assert states[-1][0] == pytest.approx(t_out + PARAMS["pickup_delay"], abs=dt + 1e-6), c["id"]
    assert pipe.decoder.stats["train_lost"] == 0
    # a front fix at each boundary the train passed from one circuit into the next
    fixes = [m for m in ms if isinstance(m, PositionFix)]
    assert len(fixes) == len(table) - 1
    assert all(f.direction == sign for f in fixes)
    traj = sc.trajectory()
    for f in fixes:
        err = f.position - np.interp(f.stamp, traj.t, traj.position)
        zone = table[0]["zone"]
        # the drop is where the new circuit's line begins (near edge of the zone): the fix is
        # centred there, off by the sampling of the onset only
        assert abs(err) <= abs(speed) * dt + 0.1, (f, err)
        assert f.position_stddev == pytest.approx(math.sqrt(1.25) * 0.5 * zone, rel=0.01)
    assert sum(pipe.rejected.values()) == 0


def test_decoded_blocks_are_the_same_from_a_pipeline_without_the_simulator():
    sc = scenario(duration=30.0)
    blocks, ms, pipe = run_offline(NODE, sc)
    other = SensorPipeline(spec(NODE), sc.sensors[NODE], sc.track, sc.vehicle, simulate=False)
    again = [m for b in blocks for m in other.on_block(b)]
    assert again == ms


# -- faults ---------------------------------------------------------------------------------

def test_poor_shunt_light_vehicle_is_not_seen_and_the_loss_is_flagged():
    """The dangerous side: a light 4-axle vehicle on rusty rail in TC01 shunts with 20 Ohm
    per axle; TC01's level stays up while it is in the circuit and TC01 never reports it.
    When TC00 clears with no neighbour holding the train, TC01 becomes DISTURBED."""
    light = [2.0, 4.5, 12.0, 14.5]
    sc = scenario(speed=40.0, start=100.0, duration=110.0, vehicle_axles=light,
                  params={"faults": "TC01@0:poor_shunt"})
    blocks, ms, pipe = run_offline(NODE, sc)
    table = tc.circuit_table(sc.track, pipe.params)
    t_in, t_out = axle_span_times(sc, table[1])
    times = np.concatenate([b.times() for b in blocks])
    lv = np.concatenate([b.channel("TC01.level") for b in blocks])
    inside = (times > t_in) & (times < t_out)
    assert inside.sum() > 1000 and lv[inside].min() > PARAMS["threshold_pick"]   # the simulator: not shunted
    states = transitions(ms)["TC01"]
    assert OCCUPIED not in [s for _, s in states]                                  # not seen
    assert states[-1][1] == DISTURBED                                              # but flagged
    t_lost = states[-1][0]
    assert t_in < t_lost < t_out
    assert pipe.decoder.stats["train_lost"] == 1
    # no boundary fix into or out of the lost circuit; the next hand-over (TC02 -> TC03) has one
    fixes = [m for m in ms if isinstance(m, PositionFix)]
    assert [f.reference_id for f in fixes] == ["TC02/TC03"]
    # reset by the operator: follows its receiver again
    pipe.decoder.reset_section("TC01")
    assert pipe.decoder.state[1] == CLEAR


def test_poor_shunt_of_a_long_train_is_seen_late_by_its_many_axles():
    """32 axles of 20 Ohm in parallel still shunt in the middle of the circuit: TC01 drops,
    but far later than with a good shunt."""
    sc = scenario(params={"faults": "TC01@0:poor_shunt"}, duration=40.0)
    good = scenario(duration=40.0)
    late = transitions(run_offline(NODE, sc)[1])["TC01"][1]
    normal = transitions(run_offline(NODE, good)[1])["TC01"][1]
    assert late[1] == normal[1] == OCCUPIED
    assert late[0] - normal[0] > 50.0 / V300


@pytest.mark.parametrize("kind", ["broken_rail", "tx_failed"])
def test_broken_rail_or_failed_transmitter_is_occupied_with_no_train(kind):
    """The safe side: TC02 drops at 5 s although the train (standing in TC00) is 1.5 km away."""
    sc = scenario(speed=0.0, start=600.0, duration=12.0, params={"faults": f"TC02@5:{kind}"})
    blocks, ms, pipe = run_offline(NODE, sc)
    trans = transitions(ms)
    assert trans["TC02"] == [(0.0, CLEAR), (pytest.approx(5.0 + PARAMS["drop_delay"], abs=0.011), OCCUPIED)]
    assert [s for _, s in trans["TC00"]] == [CLEAR, OCCUPIED]
    assert [s for _, s in trans["TC01"]] == [CLEAR] and [s for _, s in trans["TC03"]] == [CLEAR]
    assert not any(isinstance(m, PositionFix) for m in ms)   # no neighbour occupied: no hand-over


def test_a_drop_ahead_too_soon_after_the_train_entered_gives_no_fix():
    """A broken rail in TC02 4 s after the train entered TC01 (1,500 m, crossed in 15 s at
    most at max_speed): TC02 OCCUPIED, but no boundary fix (withheld)."""
    sc = scenario(start=1350.0, duration=10.0, params={"faults": "TC02@6:broken_rail"})
    blocks, ms, pipe = run_offline(NODE, sc)
    fixes = [m for m in ms if isinstance(m, PositionFix)]
    assert [f.reference_id for f in fixes] == ["TC00/TC01"]
    assert OCCUPIED in [s for _, s in transitions(ms)["TC02"]]
    assert pipe.decoder.stats["fix_withheld"] == 1


def test_adjacent_frequency_interference_masks_the_train():
    """A failed tuning unit lets TC02's carrier into TC01's receiver: TC01 holds its level
    under the train (the dangerous side) and the loss is flagged when TC00 clears."""
    sc = scenario(duration=40.0, params={"faults": "TC01@0:interference"})
    blocks, ms, pipe = run_offline(NODE, sc)
    table = tc.circuit_table(sc.track, pipe.params)
    t_in, t_out = axle_span_times(sc, table[1])
    times = np.concatenate([b.times() for b in blocks])
    lv = np.concatenate([b.channel("TC01.level") for b in blocks])
    middle = (times > t_in + 2.0) & (times < t_out - 5.0)   # train well inside, not at TC02's transmitter
    assert lv[middle].min() > PARAMS["threshold_pick"]
    states = [s for _, s in transitions(ms)["TC01"]]
    assert OCCUPIED not in states and states[-1] == DISTURBED
    assert pipe.decoder.stats["train_lost"] == 1
    # without the fault the neighbour's carrier is filtered: TC01 sees the train
    clean = scenario(duration=40.0)
    assert OCCUPIED in [s for _, s in transitions(run_offline(NODE, clean)[1])["TC01"]]


def test_malformed_fault_strings_are_refused():
    for text in ("TC01:poor_shunt", "TC01@x:broken_rail", "TC09@1:tx_failed", "TC01@1:melted"):
        with pytest.raises(ValueError):
            tc.parse_faults(text, ["TC00", "TC01"])
    assert tc.parse_faults("TC01@2-5:poor_shunt; TC00@1:tx_failed", ["TC00", "TC01"]) == \
        [(1, 2.0, 5.0, "poor_shunt"), (0, 1.0, math.inf, "tx_failed")]


# -- decoder input ----------------------------------------------------------------------------

def test_decoder_rejects_malformed_blocks_and_keeps_its_state():
    sc = scenario(duration=3.0)
    blocks, ms, pipe = run_offline(NODE, sc)
    dec = tc.TrackCircuitDecoder(pipe.params, sc.track)
    for b in blocks[:5]:
        dec.decode(b)
    before = (dec.low.copy(), dec.edge.copy(), list(dec.state), dec._last_report)
    b = blocks[5]
    bad = [
        (RawBlock(b.sensor, b.unit_id, b.seq, b.t0, b.sample_rate, ("TC00.level", "TC01.level", "TC02.level",
                                                                     "TC99.level"), b.units, b.data), "unknown_id"),
        (RawBlock(b.sensor, b.unit_id, b.seq, b.t0, b.sample_rate, b.channels[::-1], b.units, b.data), "channels"),
        (RawBlock(b.sensor, b.unit_id, b.seq, b.t0, b.sample_rate, b.channels[:2], b.units[:2], b.data[:, :2]),
         "channels"),
        (RawBlock(b.sensor, b.unit_id, b.seq, b.t0, b.sample_rate, b.channels, b.units, b.data + 10.0), "implausible"),
        (RawBlock(b.sensor, b.unit_id, b.seq, b.t0, b.sample_rate, b.channels, b.units, b.data - 5.0), "implausible"),
    ]
    for block, reason in bad:
        with pytest.raises(InputRejected) as exc:
            dec.decode(block)
        assert exc.value.reason == reason
    after = (dec.low, dec.edge, dec.state, dec._last_report)
    assert np.array_equal(before[0], after[0]) and np.array_equal(before[1], after[1])
    assert before[2:] == after[2:]
    assert dec.decode(b) is not None   # valid data goes on
    with pytest.raises(InputRejected):
        RawBlock.from_samples(b.sensor, b.unit_id, 99, b.t0, b.sample_rate, b.channels, b.units,
                              np.full(b.data.shape, np.nan))


def test_registered_with_an_error_model_and_occupancy_output():
    assert NODE in NODE_NAMES
    s = spec(NODE)
    assert s.sensor == "track_circuit" and set(s.outputs) == {"position", "sections"}
    sc = scenario()
    em = s.errors(resolve_params(s.params, {}), sc.track, Vehicle())
    assert em.measures == "position" and em.fix_bias_sigma == pytest.approx(12.0) and "miscount" in em.faults
    blocks, ms, pipe = run_offline(NODE, sc, t_end=2.0)
    occ = [m for m in ms if isinstance(m, SectionOccupancy)]
    assert occ and all(m.source == "track_circuit" for m in occ)
    assert [s.section_id for s in occ[0].sections] == ["TC00", "TC01", "TC02", "TC03"]
    assert blocks[0].channels == ("TC00.level", "TC01.level", "TC02.level", "TC03.level")


# -- error model: floor and references ------------------------------------------------------

MIXED = [{"every": 1500.0, "start": 0.0, "end": 1500.0, "id": "TC{n:02d}", "length": 1500.0, "system": "UM71C"},
         {"id": "TI00", "start": 3000.0, "end": 3800.0, "system": "TI21", "zone": 30.0},
         {"id": "TI01", "start": 3800.0, "end": 4600.0, "system": "TI21"}]    # zones 24 | 30 | 20 m


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_every_decoded_fix_passes_the_error_model(seed):
    """Randomised runs over UM71C and TI21 circuits of different zones (3..10 m/s over one joint,
    40..83 m/s over all three, both ways, the train leading or backing; trains of 1-8 cars, the
    last axle known or not, UM71C zone length, front_first): the model built from the run's
    parameters refuses no boundary fix."""
    rng = np.random.default_rng(seed)
    total = 0
    for sign in (1, -1):
        for slow in (True, False):
            speed = sign * (rng.uniform(3.0, 10.0) if slow else rng.uniform(40.0, V300))
            orient = int(rng.choice([-1, 1]))
            ax = axles(int(rng.integers(1, 9)))
            params = {"orientation": orient, "last_axle_offset": float(max(ax)) if rng.random() < 0.7 else 0.0,
                      "zone_um71c": float(rng.uniform(18.0, 26.0)), "front_first": bool(rng.random() < 0.2)}
            if slow:   # the leading axle 40 m before a joint
                joint = float(rng.choice([1500.0, 3000.0, 3800.0]))
                start = joint - sign * 40.0 + (orient * max(ax) if orient != sign else 0.0)
                duration = 100.0 / abs(speed)
            else:
                start, duration = (300.0 if sign > 0 else 4400.0), 4000.0 / abs(speed)
            sc = scenario(MIXED, speed=speed, start=start, duration=duration, params=params, vehicle_axles=ax)
            run = simulate_and_decode(NODE, dataclasses.replace(sc, seed=seed))
            model = run.pipe.spec.errors(run.pipe.params, run.pipe.track, sc.vehicle)
            # the shortest zone (TI21's 20 m or UM71C's) and a 100 Hz sample of 100 m/s
            shortest = min(20.0, params["zone_um71c"])
            assert model.min_stddev == pytest.approx(math.sqrt(1.25 * (0.5 * shortest) ** 2 + 0.02 ** 2
                                                               + (100.0 / 100.0) ** 2 / 12.0))
            fixes = [m for m in run.measurements if isinstance(m, PositionFix)]
            assert [model.refusal(f) for f in fixes] == [None] * len(fixes)
            # a backing train gives fixes only with its last axle known (or taken to lead)
            gives = orient == sign or params["front_first"] or params["last_axle_offset"] > 0.0
            assert len(fixes) == (1 if slow else 3) * gives
            total += len(fixes)
    assert total >= 4


def test_forged_track_circuit_fixes_are_refused_with_their_reason():
    params = resolve_params(tc.PARAMS, {"first_axle_offset": FIRST_AXLE, "last_axle_offset": 198.0})
    model = spec(NODE).errors(params, track(MIXED), Vehicle())
    assert model.min_stddev == pytest.approx(math.sqrt(1.25 * 10.0 ** 2 + 0.02 ** 2 + 1.0 / 12.0))
    assert set(model.references.windows) == {"TC00/TC01", "TC01/TI00", "TI00/TI01"}
    # joint TC01/TI00 at 3000 m: entering TI00 upwards (zone 30 m) the drop is 15 m before it, entering
    # TC01 downwards (24 m) 12 m after it; the front 3 m ahead of the first axle or 198 m behind the last
    assert model.references.windows["TC01/TI00"] == pytest.approx((3000.0 - 15.0 - 198.0, 3000.0 + 12.0 + 198.0))
    # without the last axle (no fix while backing): the first axle only
    lead = spec(NODE).errors({**params, "last_axle_offset": 0.0}, track(MIXED), Vehicle())
    assert lead.references.windows["TC01/TI00"] == pytest.approx((3000.0 - 15.0 + 3.0, 3000.0 + 12.0 - 3.0))
    honest = PositionFix(10.0, "track_circuit", "track_circuit", "T", "TC01/TI00", 2988.0, 13.4, 1)
    assert_forged_fixes_refused(lead, honest, "TC00/TI00", 3009.0 + 300.0)   # the unknown id: not neighbours
    assert spec(NODE).errors(params, None, Vehicle()).references is None
