"""The shared admission of the consumers of the fused state (core/safety, docs/reliability.md):
StreamAdmission's reasons, what moves a stream and when it is stale; MotionGate's kinematic
plausibility."""
from __future__ import annotations

import math

import pytest

from train_localization.core.safety.admission import PARAMS, StreamAdmission, StreamLimits, limits_from
from train_localization.core.safety.plausibility import Motion, MotionGate
from train_localization.core.signals import MAX_ID_LENGTH, InputRejected


def reason(refusal: InputRejected | None) -> str | None:
    return None if refusal is None else refusal.reason


# ---------------------------------------------------------------- StreamAdmission

def test_each_threat_is_refused_with_its_reason_and_counted():
    s = StreamAdmission("state", StreamLimits(future=0.5, timeout=1.0, max_items=3))
    now = 100.0
    assert s.admit(99.0, now) is None
    cases = [
        ((math.nan, now), {}, "nan"),
        ((99.1, now), {"values": {"position": math.inf}}, "nan"),
        ((99.1, now), {"values": {"speed": 250.0}, "limits": {"speed": (-200.0, 200.0)}}, "implausible"),
        ((99.1, now), {"ids": {"track_id": "x" * (MAX_ID_LENGTH + 1)}}, "too_long"),
        ((99.1, now), {"sizes": {"sections": 4}}, "too_large"),
        ((100.6, now), {}, "future"),
        ((99.0, now), {}, "duplicate"),
        ((98.0, now), {}, "stamp_back"),
    ]
    for (stamp, clock), checks, why in cases:
        refusal = s.admit(stamp, clock, **checks)
        assert reason(refusal) == why, (stamp, checks)
        assert "\n" not in str(refusal)
    assert s.refused == {"nan": 2, "implausible": 1, "too_long": 1, "too_large": 1, "future": 1, "duplicate": 1,
                         "stamp_back": 1}
    assert s.admitted == 1
    # at the limits: taken
    assert s.admit(100.5, now, values={"speed": 200.0}, limits={"speed": (-200.0, 200.0)},
                   ids={"track_id": "x" * MAX_ID_LENGTH}, sizes={"sections": 3}) is None
    assert s.admitted == 2 and sum(s.refused.values()) == 8


def test_without_a_clock_nothing_is_future_and_an_unordered_stream_takes_any_order():
    s = StreamAdmission("events", StreamLimits(ordered=False))
    for stamp in (5.0, 1e9, 3.0, 3.0):
        assert s.admit(stamp, 0.0) is None
    assert s.admitted == 4 and not s.refused and s.last_stamp == 1e9
    assert reason(s.admit(1e9, 10.0)) == "future"      # with a clock: ahead of it


def test_only_an_admitted_message_moves_the_stream():
    s = StreamAdmission("state", StreamLimits(future=0.5, timeout=1.0))
    assert s.admit(10.0, 10.0) is None
    assert reason(s.admit(1e6, 10.1)) == "future"      # one stamped far ahead ...
    assert s.last_stamp == 10.0 and s.admitted_at == 10.0
    for k in range(1, 4):                              # ... is not the reference of the real ones
        assert s.admit(10.0 + 0.1 * k, 10.1 + 0.1 * k) is None
    assert s.last_stamp == pytest.approx(10.3) and s.admitted == 4
    assert reason(s.admit(math.nan, 10.5)) == "nan"
    assert s.admitted_at == pytest.approx(10.4)
    # check alone moves nothing; accept does
    s.check(10.5, 10.6)
    assert s.last_stamp == pytest.approx(10.3)
    s.accept(10.5, 10.6)
    assert (s.last_stamp, s.admitted_at, s.admitted) == (10.5, 10.6, 5)


def test_stale_after_the_time_out_from_waiting_since_and_from_the_last_admission():
    s = StreamAdmission("sections", StreamLimits(timeout=2.0))
    assert s.silence(50.0) == math.inf and s.stale(50.0)            # never expected, never seen
    s.waiting_since(50.0)
    s.waiting_since(51.0)                                            # the first call counts
    assert not s.stale(52.0) and s.stale(52.01)
    assert s.admit(52.5, 52.5) is None
    assert s.silence(54.0) == pytest.approx(1.5) and not s.stale(54.5) and s.stale(54.51)
    # refused messages do not keep it alive
    for k in range(10):
        s.admit(52.5, 53.0 + 0.2 * k)                                # duplicates
    assert s.refused["duplicate"] == 10 and s.stale(54.6)
    s.reset()
    assert s.stale(60.0) and s.refused["duplicate"] == 10 and s.admitted == 1
    assert s.admit(1.0, 60.0) is None                                # order forgotten: an earlier stamp taken


def test_limits_come_from_the_parameters_and_must_be_positive():
    lim = limits_from({"future_tolerance": 0.25, "input_timeout": 3.0}, max_items=7, ordered=False)
    assert lim == StreamLimits(0.25, 3.0, 7, False)
    assert StreamLimits() == StreamLimits(PARAMS["future_tolerance"].default, PARAMS["input_timeout"].default)
    for bad in ({"future": 0.0}, {"timeout": -1.0}, {"max_items": 0}):
        with pytest.raises(ValueError, match="positive"):
            StreamLimits(**bad)


# ---------------------------------------------------------------- MotionGate

def motion(t, lo, hi, v, dv=0.5, claimed=True):
    return Motion.of(t, claimed, lo, hi, v, dv)


def test_a_state_out_of_reach_is_refused_and_one_within_reach_taken():
    gate = MotionGate(max_acceleration=5.0, margin=1.0, speed_margin=1.0)
    gate.check(motion(0.0, 995.0, 1005.0, 20.0))            # no reference yet: anything passes
    gate.accept(motion(0.0, 995.0, 1005.0, 20.0))
    r = gate.reach(1.0)
    assert (r.lo, r.hi) == pytest.approx((995.0 + 19.5 - 2.5, 1005.0 + 20.5 + 2.5))
    assert (r.v_lo, r.v_hi) == pytest.approx((14.5, 25.5))
    gate.check(motion(1.0, 1015.0, 1025.0, 20.0))           # where the train went: taken
    for far in (motion(1.0, 6000.0, 6010.0, 20.0), motion(1.0, 980.0, 1009.0, 20.0)):   # 5 km ahead, behind
        with pytest.raises(InputRejected) as exc:
            gate.check(far)
        assert exc.value.reason == "motion" and "out of reach" in str(exc.value)
    # the margin: an interval 0.9 m beyond the reach passes, 1.1 m does not
    gate.check(motion(1.0, r.hi + 0.9, r.hi + 5.0, 20.0))
    with pytest.raises(InputRejected):
        gate.check(motion(1.0, r.hi + 1.1, r.hi + 5.0, 20.0))
    assert gate.last.lo == 995.0                            # check moves nothing


def test_a_standstill_claimed_during_a_run_at_20_m_s_is_refused():
    gate = MotionGate()
    gate.accept(motion(0.0, 995.0, 1005.0, 20.0, dv=0.1))
    with pytest.raises(InputRejected, match="speed") as exc:
        gate.check(motion(0.1, 996.0, 1007.0, 0.0, dv=0.1))   # in place, but at rest
    assert exc.value.reason == "motion"
    gate.check(motion(0.1, 996.0, 1007.0, 19.6, dv=0.1))      # braking at 4 m/s^2: taken
    # 4 s later a standstill is within reach (20 m/s braked at 5 m/s^2)
    gate.check(motion(4.0, 1020.0, 1080.0, 0.0, dv=0.1))


def test_the_reach_grows_with_time_so_a_relocated_stream_is_taken_again_later():
    gate = MotionGate(max_acceleration=1.0, margin=0.0, speed_margin=0.0)
    gate.accept(motion(0.0, 0.0, 10.0, 0.0, dv=0.0))          # at rest at 0 .. 10 m
    moved = 510.0                                              # the real train was reset 500 m on
    refused_until = None
    for k in range(1, 60):
        t = float(k)
        try:
            gate.check(motion(t, moved, moved + 10.0, 0.0, dv=float(k)))
        except InputRejected:
            refused_until = t
            continue
        break
    # from rest at 1 m/s^2 the front reaches 500 m after sqrt(1000) = 31.6 s
    assert refused_until == 31.0 and t == 32.0
    gate.accept(motion(t, moved, moved + 10.0, 0.0, dv=32.0))
    assert gate.last.t == 32.0


def test_the_reach_is_bounded_by_the_top_speed():
    gate = MotionGate(max_acceleration=50.0, margin=0.0, max_speed=100.0)
    gate.accept(motion(0.0, 0.0, 0.0, 0.0, dv=0.0))
    r = gate.reach(10.0)
    assert (r.lo, r.hi) == (-1000.0, 1000.0)                   # not a t^2 / 2 = 2,500 m


def test_an_unclaimed_state_passes_and_is_not_the_reference():
    gate = MotionGate()
    lost = motion(1.0, -math.inf, math.inf, math.nan, claimed=False)
    gate.check(lost)
    gate.accept(lost)
    assert gate.last is None and gate.reach(2.0) is None
    gate.accept(motion(2.0, 100.0, 110.0, 10.0))
    gate.check(motion(3.0, 5e6, 5e6 + 1.0, 10.0, claimed=False))   # claims nothing: nothing to compare
    gate.accept(motion(3.0, 5e6, 5e6 + 1.0, 10.0, claimed=False))
    assert gate.last.lo == 100.0                                  # still the claimed one
    gate.accept(motion(4.0, math.nan, 110.0, 10.0))               # a non-finite claim is no reference
    assert gate.last.t == 2.0
    gate.reset()
    assert gate.last is None


def test_the_gate_refuses_limits_that_are_not_positive():
    for bad in ({"max_acceleration": 0.0}, {"margin": -1.0}, {"speed_margin": -0.1}, {"max_speed": 0.0}):
        with pytest.raises(ValueError, match="motion gate"):
            MotionGate(**bad)
    gate = MotionGate.from_params({"max_acceleration": 2.0, "plausibility_margin": 3.0, "speed_margin": 0.5})
    assert (gate.a, gate.margin, gate.speed_margin) == (2.0, 3.0, 0.5)
