"""ETCS data on a network (core/etcs/network_data.py): balise groups located on sections and
linking that follows the routes (docs/network.md, "ETCS on a network")."""
from __future__ import annotations

import pytest
import yaml

from train_localization.core.etcs.network_data import NetworkEtcsData
from train_localization.core.network import Network
from train_localization.core.paths import resolve
from train_localization.core.track import TrackError


def _throat(etcs: dict | None = None, change=None) -> Network:
    data = yaml.safe_load(open(resolve("config/track_throat.yaml"), encoding="utf-8"))
    data["etcs"] = {"q_nvlocacc": 12.0, "linking": "auto"} if etcs is None else etcs
    if change:
        change(data)
    return Network.from_dict(data)


def test_groups_are_located_on_their_sections_and_link_to_the_next_group_on_every_path():
    net = _throat()
    data = NetworkEtcsData.from_network(net)
    assert (data.groups["BG5a"].section, data.groups["BG5a"].group.reference) == ("T5", 120.0)
    assert data.group_of_balise["BG7b"] == "BG7b" and data.q_nvlocacc == 12.0
    assert [(k.to_bg, k.distance, k.path) for k in data.links_after("BG1a", 1)] == [("BG1b", 3.0, ("T1",))]
    t3 = net.section("T3").length
    # after BG1b towards W1: the next group on each way, at its distance along that way
    ahead = data.links_after("BG1b", 1)
    assert [(k.to_bg, k.path, k.ways) for k in ahead] == [
        ("BG2a", ("T1", "T2"), (("W1", "B1"),)), ("BG5a", ("T1", "T3", "T5"), (("W1", "B2"),))]
    assert [k.distance for k in ahead] == [pytest.approx(397.0 + 120.0), pytest.approx(397.0 + t3 + 120.0)]
    # backwards from BG5a through W2, a facing switch for a train running against T5's chainage
    back = data.links_after("BG5a", -1)
    assert [(k.to_bg, k.path, k.ways) for k in back] == [
        ("BG1b", ("T5", "T3", "T1"), (("W2", "B2"),)), ("BG4b", ("T5", "T4"), (("W2", "B1"),))]
    assert [k.distance for k in back] == [pytest.approx(120.0 + t3 + 397.0), pytest.approx(120.0 + 497.0)]
    # the link a train expects is the one on its route (or its most probable hypothesis's path)
    assert data.link_on("BG1b", 1, ["T1", "T3", "T5", "T6"]).to_bg == "BG5a"
    assert data.link_on("BG1b", 1, ["T1", "T2"]).to_bg == "BG2a"
    assert data.links_after("BG3b", 1) == ()            # T2 ends the network: nothing beyond
    assert NetworkEtcsData.from_network(net, reach=550.0).links_after("BG1b", 1)[0].to_bg == "BG2a"
    assert len(NetworkEtcsData.from_network(net, reach=550.0).links_after("BG1b", 1)) == 1


def _dup(data):
    data["sections"][1]["equipment"]["eurobalise"].append({"id": "BGx", "position": 300.0, "group": "BG1a"})


@pytest.mark.parametrize("etcs, change, message", [
    ({"linking": "auto"}, None, "no q_locacc and track T1 no national value"),
    ({"q_nvlocacc": 12.0, "linking": [{"from": "BG1a", "to": "BG1b", "distance": 3.0}]}, None,
     "must be 'auto' on a network"),
    ({"q_nvlocacc": 12.0, "linkage": "auto"}, None, "unknown keys in 'etcs': linkage"),
    ({"q_nvlocacc": 12.0}, _dup, "BG1a is on sections T1 and T2"),
])
def test_inconsistent_network_etcs_data_is_refused_in_one_line(etcs, change, message):
    with pytest.raises(TrackError, match=message) as err:
        NetworkEtcsData.from_network(_throat(etcs, change))
    assert "\n" not in str(err.value)
