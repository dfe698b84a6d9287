"""bags/network_line.mcap (docs/network.md, "The network line"): three trains on the double-track
line with two stations, recorded live, each supervised by ETCS to an end of authority that lies
over switches, one switch reported the wrong way by the interlocking. Scored per train from the
MCAP file alone (scripts/score_bag.py: mcap's ROS 2 decoder, the truth's section and chainage)."""
from __future__ import annotations

import pytest
import yaml
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from conftest import ROOT, outside_scorer

BAG = ROOT / "bags" / "network_line.mcap"
TRAINS = {"/ice": "L1", "/reg": "S1", "/ic": "U3"}   # namespace -> the section of its end of authority


@pytest.fixture(scope="module")
def scores():
    return outside_scorer().score_bag(str(BAG))


def _last(topics: list[str]) -> dict:
    """topic -> the last message recorded on it."""
    last = {}
    with open(BAG, "rb") as fh:
        for _, channel, _, msg in make_reader(fh, decoder_factories=[DecoderFactory()]).iter_decoded_messages(
                topics=topics):
            last[channel.topic] = msg
    return last


def test_every_train_is_inside_and_never_nominal_on_a_wrong_track(scores):
    assert sorted(scores) == sorted(TRAINS)
    for ns, s in scores.items():
        assert s["states"] > 1500, (ns, s)       # 25 Hz over the 68 s
        assert s["outside"] == 0 and s["nominal_outside"] == 0 and s["nominal_wrong_track"] == 0, (ns, s)


def test_the_true_front_lies_within_the_etcs_safe_front_ends_and_no_train_passes_its_authority(scores):
    for ns, s in scores.items():
        etcs = s["etcs"]
        assert etcs["reports"] > 1500 and etcs["etcs_inside"] >= 0.999, (ns, etcs)
        assert etcs["overruns"] == 0 and etcs["trips"] == 0, (ns, etcs)
        assert 0.0 < etcs["eoa_margin"] < 50.0, (ns, etcs)   # stopped short of it, at its platform or buffer stop


def test_each_authority_lies_over_switches_and_each_train_ends_on_its_section():
    """The ends of authority are beyond facing switches of the routes (the scenario in the bag),
    reg's W3 is reported the wrong way, and every train's last fused state names the section of
    its end of authority: the way found over every switch."""
    last = _last(["/scenario", "/reg/interlocking/switches", *(f"{ns}/localization/state" for ns in TRAINS)])
    entries = {f"/{t['name']}": t for t in yaml.safe_load(last["/scenario"].data)["trains"]}
    for ns, section in TRAINS.items():
        route = entries[ns]["route"]["sections"]
        assert entries[ns]["atp"]["end_of_authority_section"] == section and route.index(section) > 0, ns
        assert last[f"{ns}/localization/state"].track_id == section, ns
    reported = last["/reg/interlocking/switches"]
    assert dict(zip(reported.switch_ids, reported.positions))["W3"] == "B1"   # the route takes B2, into S1
