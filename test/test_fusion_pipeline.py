"""The fusion's per-reading pipeline (core/fusion/pipeline.py): the routing of the verdicts, the
innovation renewed after a stage that replaced the covariance, and stages on a fake filter; the
policies switched off by configuration (FusionConfig.policies)."""
from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from train_localization.core.fusion import FusionConfig, TrainFilter, pipeline
from train_localization.core.fusion.bookkeeping import Bookkeeping
from train_localization.core.fusion.config import POLICIES, sensor_models
from train_localization.core.fusion.events import LoneTakeFix, Relearn, RelearnFault, Separate, Suspend
from train_localization.core.fusion.pipeline import DONE, EXCLUDED, GO_ON, Reading, Step, Verdict, apply_reading
from train_localization.core.measurements import PositionFix, SpeedMeasurement
from train_localization.core.scenario import Vehicle


class FakeEKF:
    """An EKF's x and P, with the covariance's revision counted as CountingEKF does."""

    def __init__(self):
        self.x, self._P, self.revision = np.zeros((3, 1)), np.eye(3), 0

    @property
    def P(self):
        return self._P

    @P.setter
    def P(self, value):
        self._P, self.revision = value, self.revision + 1


def fake_filter(**extra):
    """A fake filter: its bookkeeping, EKF, gates and an innovation that counts its calls."""
    f = SimpleNamespace(aux=Bookkeeping(), ekf=FakeEKF(), calls=[], layout=SimpleNamespace(episode_sensors=(), fix=(), relative=frozenset({"doppler"}), accelerometers=frozenset()),
                        limits=SimpleNamespace(gates={"doppler": 9.0, "eb": 9.0}, bounded=frozenset(), transient_bounds={},
                                               persistent=frozenset()),
                        cfg=SimpleNamespace(slip_min_drive=0.2, jerk_psd=0.1, branch_timeout=120.0))
    f.__dict__.update(extra)

    def innovation(m):
        f.calls.append("innovation")
        return 1.0, 0.1, np.array([0.0, 1.0, 0.0]), 0.0, np.array([0.0, 1.0, 0.0]), 1.1
    f.innovation = innovation
    return f


SPEED = SpeedMeasurement(1.0, "doppler", "doppler", 10.0, 0.1)
FIX = PositionFix(1.0, "eb", "eb", "T", "EB1", 100.0, 0.3)


def _stage(name, verdict=GO_ON, new_covariance=False):
    def judge(f, r):
        f.calls.append(name)
        if new_covariance:
            f.ekf.P = f.ekf.P.copy()
        return verdict
    return judge


def test_the_pipeline_stops_at_the_first_stage_that_is_done_with_the_reading():
    f = fake_filter()
    apply_reading(f, SPEED, (Step(_stage("a")), Step(_stage("b", DONE)), Step(_stage("c"))))
    assert f.calls == ["a", "b"]


def test_an_excluded_reading_goes_to_its_sensors_episode_and_no_further():
    f = fake_filter(episodes=SimpleNamespace(outlasted=lambda *args: (f.calls.append("outlasted"), ())[1]))
    f.limits.bounded = frozenset({"doppler"})
    apply_reading(f, SPEED, (Step(pipeline.innovation), Step(_stage("a", EXCLUDED)), Step(_stage("c"))))
    assert f.calls == ["innovation", "a", "outlasted"]


def test_the_innovation_is_renewed_only_after_a_declared_stage_that_replaced_the_covariance():
    f = fake_filter()
    stages = (Step(pipeline.innovation), Step(_stage("same"), renew=True), Step(_stage("new", new_covariance=True)),
              Step(_stage("renewing", new_covariance=True), renew=True), Step(_stage("end", DONE)))
    apply_reading(f, SPEED, stages)
    assert f.calls == ["innovation", "same", "new", "renewing", "innovation", "end"]


def test_the_bookkeeping_is_copied_before_the_stages_change_it():
    f = fake_filter()
    before = f.aux
    apply_reading(f, SPEED, (Step(pipeline.innovation), Step(pipeline.gate)))
    assert f.aux is not before and before.gated == {} and f.aux.gated == {}


def test_the_gate_stage_counts_a_reading_beyond_its_gate_and_keeps_an_unexplained_fix():
    f = fake_filter(fixes=SimpleNamespace(unexplained=lambda m, z, R: (f.calls.append(("unexplained", m.sensor)), ())[1],
                                          remembered=lambda m, R: False))
    f.aux.initialised = True
    r = Reading(FIX, "eb", True, z=110.0, R=0.09, hx=100.0, S=1.0, nis=100.0)
    assert pipeline.gate(f, r) == DONE
    assert f.aux.gated == {"eb": 1} and f.calls == [("unexplained", "eb")]
    r = Reading(FIX, "eb", True, z=100.5, R=0.09, hx=100.0, S=1.0, nis=0.25)
    assert pipeline.gate(f, r) == GO_ON and f.aux.gated == {"eb": 1}


def test_the_suspension_stage_excludes_what_the_arbitration_keeps_suspended_and_passes_on_its_effects():
    verdicts = iter([(True, (Separate(SPEED, 1.0, 1.0),)), (False, (RelearnFault("doppler"),))])
    f = fake_filter(arbitration=SimpleNamespace(suspended=lambda m, e, S, nis, common: next(verdicts)),
                    episodes=SimpleNamespace(common=lambda cls, h: 0.0))
    r = Reading(SPEED, "doppler", False, z=10.0, R=0.01, h=np.zeros(3), hx=9.0, S=1.0, nis=1.0)
    assert pipeline.suspension(f, r) == GO_ON          # not suspended: not asked
    f.aux.suspended = {"doppler": None}
    assert pipeline.suspension(f, r) == Verdict(pipeline.Kind.EXCLUDED, (Separate(SPEED, 1.0, 1.0),))
    assert pipeline.suspension(f, r) == Verdict(pipeline.Kind.GO_ON, (RelearnFault("doppler"),))


def test_events_are_routed_in_order_and_the_ones_they_ask_come_right_after_them():
    f = fake_filter()
    f.arbitration = SimpleNamespace(relearn_fault=lambda cls: (f.calls.append(("relearn", cls)),
                                                               (Suspend("wheel", None),))[1],
                                    suspend=lambda cls, fault: f.calls.append(("suspend", cls)))
    f.episodes = SimpleNamespace(separate=lambda m, e, S: f.calls.append(("separate", m.sensor)))
    pipeline.route(f, (RelearnFault("doppler"), Separate(SPEED, 1.0, 1.0)))
    assert f.calls == [("relearn", "doppler"), ("suspend", "wheel"), ("separate", "doppler")]


def test_the_slip_stage_asks_only_about_the_sensors_with_episodes():
    f = fake_filter(episodes=SimpleNamespace(slipping=lambda m, e, S, nis: (True, (Suspend("doppler", None),))))
    r = Reading(SPEED, "doppler", False, z=10.0, hx=9.0, S=1.0, nis=1.0)
    assert pipeline.slip(f, r) == GO_ON
    f.layout.episode_sensors = ("doppler",)
    assert pipeline.slip(f, r) == Verdict(pipeline.Kind.EXCLUDED, (Suspend("doppler", None),))


def test_the_first_fix_initialises_and_is_done():
    f = fake_filter(fixes=SimpleNamespace(initialise=lambda m: (f.calls.append("initialise"), ())[1]))
    f.layout.per_reference = ()
    assert pipeline.fix_reference(f, Reading(FIX, "eb", True)) == DONE and f.calls == ["initialise"]
    f.aux.initialised = True
    assert pipeline.fix_reference(f, Reading(FIX, "eb", True)) == GO_ON


def test_a_driven_reading_marks_the_drive():
    f = fake_filter()
    f.ekf.x[2, 0] = 0.5
    assert pipeline.transient_onset(f, Reading(SPEED, "doppler", False, S=1.0)) == GO_ON
    assert f.aux.last_drive == 1.0
    f.ekf.x[2, 0], f.aux.last_drive = 0.1, -math.inf
    pipeline.transient_onset(f, Reading(SPEED, "doppler", False, S=1.0))
    assert f.aux.last_drive == -math.inf


def _filter(off=frozenset()):
    models = sensor_models(["doppler_radar", "wheel_sensor", "eurobalise_reader"], None, Vehicle())
    return TrainFilter(FusionConfig(sensors=models, policies=frozenset(POLICIES) - frozenset(off)))


def test_policies_are_switched_off_by_configuration():
    full = _filter()
    assert full.limits.fault_bounds and full.limits.subs and full.limits.offset_bounds
    bare = _filter({"persistent_fault_cover", "transient_fault_cover", "offset_fault_cover", "own_solutions"})
    assert not (bare.limits.fault_bounds or bare.limits.transient_bounds or bare.limits.offset_bounds
                or bare.limits.subs or bare.limits.sensor_subs)
    assert bare.limits.gates == full.limits.gates and bare.limits.z == full.limits.z
    with pytest.raises(ValueError, match="policies names unknown lone_sorce"):
        FusionConfig(policies={"lone_sorce"})


def test_the_prepare_stage_predicts_notes_the_solution_before_and_the_time_since_the_sensors_last_fix():
    f = fake_filter(applied=0, predict_to=lambda t: f.calls.append(("predict", t)),
                    solutions=SimpleNamespace(main=lambda: "before"), fault_input_of=lambda m, is_fix: "input")
    f.limits.subs, f.limits.offset_bounds = {"wheel": None}, {}
    f.aux.last_accepted = {"eb": 0.25}
    assert pipeline.prepare(f, Reading(FIX, "eb", True)) == GO_ON
    assert f.calls == [("predict", 1.0)] and f.before == "before" and f.fault_input == "input"
    assert f.applied == 1 and f.since_fix == 0.75


def test_a_fix_rules_out_the_motion_model_hypotheses_it_does_not_fit():
    from train_localization.core.fusion.bookkeeping import MovedView
    from train_localization.core.fusion.motion_views import MotionViews
    f = fake_filter()
    f.motion = MotionViews(f)
    near, far = MovedView(100.0, 1.0, 0.0, 0.0, 0.0, 0.0, math.inf), MovedView(200.0, 1.0, 0.0, 0.0, 0.0, 0.0, math.inf)
    f.aux.motion_views = (near, far)
    assert pipeline.motion_views_fix(f, Reading(FIX, "eb", True, z=100.5, R=0.09)) == GO_ON
    assert f.aux.motion_views == (near,)


def test_the_decide_views_stage_asks_the_arbitration_only_for_a_fix_with_views_kept():
    answers = iter([(True, (Relearn("speed_source_faulty"),)), (False, ())])
    f = fake_filter(arbitration=SimpleNamespace(decide_relative=lambda m, z, R, hx, S, nis: next(answers)))
    r = Reading(FIX, "eb", True, z=100.0, R=0.09, hx=100.0, S=1.0, nis=0.0)
    assert pipeline.decide_views(f, r) == GO_ON                   # no view kept: not asked
    f.aux.relative_alternatives = {"wheel": None}
    assert pipeline.decide_views(f, r) == Verdict(pipeline.Kind.DONE, (Relearn("speed_source_faulty"),))
    assert pipeline.decide_views(f, r) == GO_ON
    assert pipeline.decide_views(f, Reading(SPEED, "doppler", False)) == GO_ON


def test_the_reacquisition_stage_needs_a_kept_fix_with_a_scale_opened():
    from train_localization.core.fusion.bookkeeping import UnexplainedFix
    f = fake_filter(fixes=SimpleNamespace(reacquire=lambda m: (Relearn("reacquired", ("doppler",)),)))
    r = Reading(PositionFix(1.0, "eb", "eb", "T", "EB2", 100.0, 0.3), "eb", True, z=100.0, R=0.09)
    assert pipeline.reacquisition(f, r) == GO_ON
    f.aux.alternative = UnexplainedFix(0.5, 100.2, 0.09, 0.0, 0.0, "eb", "EB1", ("doppler",))
    assert pipeline.reacquisition(f, r) == Verdict(pipeline.Kind.DONE, (Relearn("reacquired", ("doppler",)),))
    f.aux.alternative = f.aux.alternative._replace(opened=())
    assert pipeline.reacquisition(f, r) == GO_ON


def test_the_update_stage_updates_and_counts():
    from train_localization.core.fusion.episodes import Episodes
    f = fake_filter(update=lambda *args: f.calls.append("update"))
    f.episodes = Episodes(f)
    f.aux.episode_views = {"doppler": None}
    r = Reading(SPEED, "doppler", False, z=10.0, R=0.01, h=np.zeros(3), hx=9.0, PHt=np.zeros(3), S=1.0, nis=1.0)
    assert pipeline.update(f, r) == GO_ON
    assert f.calls == ["update"] and f.aux.accepted == {"doppler": 1} and f.aux.last_accepted == {"doppler": 1.0}
    assert f.aux.nis["doppler"].count == 1 and f.aux.episode_views == {}


def test_the_locate_stage_passes_on_what_the_solutions_ask_of_the_lone_source():
    f = fake_filter(solutions=SimpleNamespace(hypotheses_take_fix=lambda m: (LoneTakeFix(m, 100.0, 0.1),)))
    assert pipeline.locate(f, Reading(FIX, "eb", True)) == Verdict(pipeline.Kind.GO_ON, (LoneTakeFix(FIX, 100.0, 0.1),))
    assert pipeline.locate(f, Reading(SPEED, "doppler", False)) == GO_ON


def test_the_accept_stage_records_the_speed_source_and_passes_on_the_plausibility_effects():
    f = fake_filter(plausibility=SimpleNamespace(check_plausible=lambda: (Suspend("doppler", None),)))
    r = Reading(SPEED, "doppler", False, z=10.0, R=0.01, hx=9.0, S=1.0, nis=1.0)
    assert pipeline.accept(f, r) == Verdict(pipeline.Kind.DONE, (Suspend("doppler", None),))
    assert f.aux.speed_sources == {"doppler"}
