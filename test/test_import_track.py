"""Real track data into the network (core/network/importing, tools/import_track.py): the OSM
extract and the railML 3 file of test/fixtures import to networks whose sections, switches and
equipment are those of the fixtures, on the fixtures' geometry; what cannot be used is noted or
refused in one line."""
from __future__ import annotations

import math

import pytest
import yaml

from conftest import ROOT
from train_localization.core.geodesy import GeodeticAnchor
from train_localization.core.network.importing.alignment import fit
from train_localization.core.network.importing.build import TrackImportError
from train_localization.core.network.importing.osm import read_osm
from train_localization.core.network.importing.railml import read_railml
from train_localization.core.network.model import Network
from train_localization.tools import import_track

OSM = ROOT / "test" / "fixtures" / "osm_passing_loop.osm"
RAILML = ROOT / "test" / "fixtures" / "railml_siding.xml"
# the map points [m] around (48.2, 11.605) the OSM fixture's nodes were placed at
OSM_ANCHOR = GeodeticAnchor(48.2, 11.605)
R, HALF = 190.0, 29.269315832749   # the turnouts' arcs: radius, length of each


def equipment(net: Network) -> dict[str, tuple[str, str, float]]:
    return {it["id"]: (kind, sid, it["position"]) for sid, sec in net.sections.items()
            for kind, items in sec.equipment.items() for it in items}


def test_points_on_a_circle_fit_to_its_arcs_and_every_point_is_passed():
    pts = [(R * math.sin(a), R * (1.0 - math.cos(a))) for a in (0.0, 0.1, 0.2, 0.3)]
    f = fit(pts)
    assert f.length == pytest.approx(0.3 * R, rel=1e-9)
    assert all(k == pytest.approx(1.0 / R, rel=1e-6) for _, k in f.segments)
    assert f.chainages == pytest.approx([0.0, 0.1 * R, 0.2 * R, 0.3 * R], rel=1e-9)


def test_the_osm_extract_imports_to_its_tracks_switches_and_balises():
    imp = read_osm(OSM)
    net = imp.network
    assert imp.data["geodetic"] == {"latitude": 48.2, "longitude": 11.605}
    assert set(net.sections) == {"w1001", "w1001_1", "w1001_2", "w1001_3", "w1002", "w1003"}
    lengths = {sid: sec.length for sid, sec in net.sections.items()}
    assert lengths["w1001"] == pytest.approx(600.0, abs=0.01) and lengths["w1001_2"] == pytest.approx(300.0, abs=0.01)
    loop = 2 * 2 * HALF + 600.0 - 4 * R * math.sin(HALF / R)   # the curves' arcs and the straight between
    assert lengths["w1002"] == pytest.approx(loop, abs=0.5)       # sampled at three points per curve
    ports = {n.node_id: {p: str(e) for p, e in n.ports.items()} for n in net.switches()}
    assert ports == {"W1": {"A": "w1001.end", "B1": "w1001_1.begin", "B2": "w1002.begin"},
                     "W2": {"A": "w1001_2.begin", "B1": "w1001_1.end", "B2": "w1002.end"},
                     "W3": {"A": "w1001_2.end", "B1": "w1001_3.begin", "B2": "w1003.begin"}}
    eq = equipment(net)
    assert set(eq) == {"BG1", "BG2", "BG3", "AC1"}
    assert eq["BG1"][:2] == ("eurobalise", "w1001") and eq["BG1"][2] == pytest.approx(450.0, abs=0.02)
    assert eq["BG2"][:2] == ("eurobalise", "w1001_1") and eq["BG2"][2] == pytest.approx(450.0, abs=0.02)
    assert eq["AC1"][:2] == ("axle_counter_head", "w1001_1") and eq["AC1"][2] == pytest.approx(100.0, abs=0.02)
    assert eq["BG3"][:2] == ("eurobalise", "w1002") and eq["BG3"][2] == pytest.approx(0.5 * loop, abs=0.5)
    assert net.section("w1001").item("eurobalise", "BG1")["line_km"] == 11.95
    # on the fixture's geometry: the siding's buffer stop, and a GNSS point beside the loop
    x, y, _ = net.section("w1003").pose(net.section("w1003").length)
    assert (x, y) == pytest.approx((1100.0, -4.5), abs=0.02)
    lat, lon = OSM_ANCHOR.projection().to_geodetic(300.0, 4.3)
    assert net.project(*net.geodetic.projection().to_map(lat, lon))[0] == "w1002"
    assert [n.split(" (")[0] for n in imp.notes] == ["switch W9", "signal N1", "signal N2", "eurobalise BG9"]
    assert all("\n" not in n for n in imp.notes)


def test_the_railml_file_imports_to_its_net_elements_switch_and_balise_groups():
    imp = read_railml(RAILML)
    net = imp.network
    assert {sid: round(sec.length, 3) for sid, sec in net.sections.items()} == \
        {"ne_a": 500.0, "ne_b": 500.0, "ne_c": 258.539, "ne_d": 300.0}
    assert {n.node_id: (n.kind, {p: str(e) for p, e in n.ports.items()}) for n in net.nodes.values()} == {
        "W1": ("point_switch", {"A": "ne_a.end", "B1": "ne_b.begin", "B2": "ne_c.begin"}),
        "J1": ("link", {"A": "ne_b.end", "B": "ne_d.begin"})}
    assert equipment(net) == {"BG1a": ("eurobalise", "ne_a", 300.0), "BG1b": ("eurobalise", "ne_a", 303.0),
                              "BG2": ("eurobalise", "ne_c", 150.0), "AC1": ("axle_counter_head", "ne_b", 50.0),
                              "AC2": ("axle_counter_head", "ne_c", 50.0)}
    assert net.section("ne_a").item("eurobalise", "BG1a")["group"] == "bg1"
    # ne_d's geometry is in UTM 32N: its end is the point 800 m east of the fixture's origin
    x, y, _ = net.section("ne_d").pose(300.0)
    lat, lon = net.geodetic.projection().to_geodetic(x, y)
    assert GeodeticAnchor(48.1, 11.5).projection().to_map(lat, lon) == pytest.approx((800.0, 0.0), abs=0.05)
    x, y, _ = net.section("ne_c").pose(net.section("ne_c").length)   # the siding's end, 4.5 m to the left
    assert GeodeticAnchor(48.1, 11.5).projection().to_map(*net.geodetic.projection().to_geodetic(x, y)) == \
        pytest.approx((2 * R * math.sin(HALF / R) + 200.0, 4.5), abs=0.05)
    assert [n.split(" (")[0] for n in imp.notes] == ["trainDetectionElement of type trackCircuitBorder TC1",
                                                    "signal A1"]


def test_what_makes_no_network_is_refused_in_one_line(tmp_path):
    def osm(body: str):
        p = tmp_path / f"x{len(list(tmp_path.iterdir()))}.osm"
        p.write_text(f'<?xml version="1.0"?><osm version="0.6">{body}</osm>')
        return p
    nodes = "".join(f'<node id="{k}" lat="48.2" lon="{11.6 + 0.001 * dx}"/>' for k, dx in
                    ((1, 0), (2, 1), (3, -1), (4, 2), (5, -2)))
    star = "".join(f'<way id="{10 + k}"><nd ref="1"/><nd ref="{k}"/><tag k="railway" v="rail"/></way>'
                   for k in (2, 3, 4, 5))
    cases = [(osm(nodes), "no railway=rail way"),
             (osm(nodes.replace('lat="48.2" lon="11.601"', 'lat="48.2001" lon="11.601"') + star),
              "joins 4 track ends and is no crossing"),
             (tmp_path / "missing.osm", "no such file")]
    bad_railml = tmp_path / "bad.xml"
    bad_railml.write_text(RAILML.read_text().replace('intrinsicCoord="1.0">', 'intrinsicCoord="0.5">', 1))
    cases.append((bad_railml, "not 0 to 1"))
    garbage = tmp_path / "garbage.xml"
    garbage.write_text("<railML version='2.4'/>")
    cases.append((garbage, "no railML 3 document"))
    for path, why in cases:
        with pytest.raises(TrackImportError, match=why) as exc:
            import_track.import_file(path)
        assert "\n" not in str(exc.value)


def test_the_cli_writes_a_network_yaml_that_loads(tmp_path, capsys):
    out = tmp_path / "net.yaml"
    assert import_track.main([str(OSM), "-o", str(out), "--anchor", "48.2,11.6"]) == 0
    text = out.read_text()
    assert text.startswith("# Imported from osm_passing_loop.osm") and "# note: signal N1" in text
    net = Network.from_yaml(out)
    assert net.geodetic == GeodeticAnchor(48.2, 11.6) and len(net.sections) == 6
    assert yaml.safe_load(text)["sections"][0]["id"] == "w1001"
    assert "signal N2" in capsys.readouterr().err
    assert import_track.main([str(tmp_path / "none.osm"), "-o", str(out)]) == 2


def test_a_train_through_the_imported_osm_loop_keeps_its_track_and_interval():
    """config/scenario_osm_loop.yaml on config/track_osm_loop.yaml (the OSM fixture as the CLI
    imports it): simulated sensors and the track-selective fusion, scored against the truth."""
    from train_localization.core.network.scoring import PublishedState, network_scores
    from train_localization.core.offline import simulate_scenario
    from train_localization.core.scenario import Scenario
    assert (ROOT / "config" / "track_osm_loop.yaml").read_text() == \
        import_track.to_yaml(read_osm(OSM, network_id="osm_loop"), OSM.name)
    sc = Scenario.from_yaml(ROOT / "config" / "scenario_osm_loop.yaml")
    r = simulate_scenario(sc, fusion_rate=50.0)
    s = network_scores(sc.route, [x.stamp for x in r.truth], [x.position for x in r.truth],
                       [PublishedState.of_estimate(e) for e in r.estimates])
    assert s["inside"] == 1.0 and s["nominal_wrong_track"] == 0 and s["selectivity"] == 1.0
    assert s["switch_ways_resolved"] == s["switch_ways"] == 1
    assert s["position_error_m"]["max"] < 1.5
    assert {"eurobalise", "dgps", "wheel", "doppler"} <= set(r.runner.counters()["accepted"])
