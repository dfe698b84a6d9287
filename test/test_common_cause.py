"""Common-cause groups as track data (core/common_cause.py) and the campaign's common-cause and
ramp draws (core/hard_conditions.py)."""
import pytest

from train_localization.core import campaign, hard_conditions
from train_localization.core.common_cause import member_groups
from train_localization.core.measurements import PositionFix
from train_localization.core.track import Track

STATIONS = [{"every": 400.0, "start": 200.0, "end": 2200.0, "id": "MW{n:03d}", "offset": 5.0}]   # 6 stations


def track(common_cause):
    return Track.from_dict({"track_id": "T", "length": 3000.0, "equipment": {"mmwave_station": STATIONS},
                            "common_cause": common_cause})


def test_consecutive_groups_cut_one_kind_by_chainage():
    t = track([{"id": "TN", "cause": "timing node", "equipment": "mmwave_station", "size": 4, "prior": 1e-2}])
    assert [(g.id, g.members) for g in t.common_cause] == [
        ("TN000", ("MW000", "MW001", "MW002", "MW003")), ("TN001", ("MW004", "MW005"))]


def test_only_groups_above_the_risk_are_monitored_with_their_members_in_view():
    t = track([{"id": "A", "members": ["MW001", "MW002"], "prior": 1e-2},
               {"id": "B", "members": ["MW003", "MW004"], "prior": 1e-6}])
    ids = ["MW000", "MW001", "MW002", "MW003", "MW004"]
    assert member_groups(t.common_cause, ids, 1e-3) == [(1, 2)]
    assert member_groups(t.common_cause, ["MW000", "MW001"], 1e-3) == []   # one member in view: a single fault


def test_a_ramp_attack_grows_from_nothing_to_its_offset():
    fixes = [(float(k), PositionFix(float(k), "eurobalise", "r", "T", f"B{k}", 100.0 * k, 0.5)) for k in range(10)]
    attack = {"kind": "ramp", "sensor": "eurobalise", "t0": 2.0, "count": 4, "offset": 4.0, "sign": -1}
    out = hard_conditions.inject(fixes, attack)
    moved = [m.position - 100.0 * m.stamp for _, m in out]
    assert len(out) == 10
    assert moved == pytest.approx([0, 0, -0.5, -1.0, -1.5, -2.0, 0, 0, 0, 0])   # k / 4 of 4 sigma, sigma 0.5 m


def test_the_campaign_draws_common_causes_and_ramps_in_the_families_where_they_apply():
    drawn = {}
    for family in ("conventional", "highspeed_maglev"):
        for seed in range(20):
            conditions = campaign.generate(family, seed)["campaign"]["conditions"]
            for key in ("common_cause", "ramp"):
                for kind in conditions.get(key, {}):
                    drawn.setdefault((key, kind), family)
    assert {("common_cause", "low_adhesion"), ("common_cause", "calibration"), ("ramp", "radar")} <= set(drawn)

