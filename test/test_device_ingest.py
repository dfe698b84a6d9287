"""Device protocols into standard messages (core/ingest/nmea.py, canbus.py, streams.py; nodes
nmea_ingest and can_ingest): real NMEA 0183 sentences and CAN frames, corrupted ones refused
and counted, GNSS fixes from NMEA map-matched to the truth, and both nodes over DDS."""
from __future__ import annotations

import math
import os
import socket
import time

import can
import cantools
import pynmea2
import pytest

from conftest import ROOT, spin_until
from train_localization.core.ingest.canbus import (CanFrame, CanLimits, CanOdometryDecoder, WheelGeometry)
from train_localization.core.ingest.navsat import NavSatIngest
from train_localization.core.ingest.nmea import LineBuffer, NmeaDecoder, NmeaFix
from train_localization.core.ingest.pacing import ReplayPace
from train_localization.core.ingest import records
from train_localization.core.ingest.streams import SerialLines, StreamError, UdpLines
from train_localization.core.scenario import Scenario
from train_localization.core.sensors import spec
from train_localization.core.sensors.base import sensor_params
from train_localization.core.signals import InputRejected

DBC = ROOT / "config" / "devices" / "odometry.dbc"
SCENARIO = ROOT / "config" / "scenario_drivers.yaml"
# Real sentences: the NMEA 0183 reference examples (their checksums as published)
GGA = "$GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,*47"
RMC = "$GPRMC,123519,A,4807.038,N,01131.000,E,022.4,084.4,230394,003.1,W*6A"
VTG = "$GPVTG,054.7,T,034.4,M,005.5,N,010.2,K*48"
GSV = "$GPGSV,3,1,11,03,03,111,00,04,15,270,00,06,01,010,00,13,06,292,00*74"


def sentence(body: str) -> str:
    """``body`` with its '$' and checksum."""
    return f"${body}*{pynmea2.NMEASentence.checksum(body):02X}"


def ddmm(value: float, degree_digits: int) -> str:
    d = int(abs(value))
    return f"{d:0{degree_digits}d}{(abs(value) - d) * 60.0:09.6f}"   # a survey receiver's 6 decimals


def epoch(utc: str, lat: float, lon: float, quality: int = 2, sigma=(0.3, 0.4, 0.9)) -> list[str]:
    """A GGA and its GST (sigma latitude, longitude, altitude [m])."""
    gga = sentence(f"GNGGA,{utc},{ddmm(lat, 2)},{'N' if lat >= 0 else 'S'},{ddmm(lon, 3)},"
                   f"{'E' if lon >= 0 else 'W'},{quality},12,0.8,512.3,M,47.0,M,,")
    gst = sentence(f"GNGST,{utc},0.5,0.5,0.3,35.0,{sigma[0]},{sigma[1]},{sigma[2]}")
    return [gga, gst]


def assert_refused(take, cases: dict) -> None:
    """Each input of ``cases`` (reason -> inputs) refused by ``take`` for that reason, in one line."""
    for reason, inputs in cases.items():
        for item in inputs:
            with pytest.raises(InputRejected) as exc:
                take(item)
            assert exc.value.reason == reason, (item, exc.value)
            assert "\n" not in str(exc.value)


def test_nmea_sentences_become_fixes_with_the_gst_accuracy_and_velocities():
    dec = NmeaDecoder()
    out = []
    for line in [RMC, GGA, VTG, GSV, sentence("GPGST,123519,1.2,0.5,0.3,45.0,0.4,0.6,1.1"),
                 "$PGRME,15.0,M,45.0,M,25.0,M*1C"]:
        out += dec.feed(line)
    fix, = [r for r in out if isinstance(r, NmeaFix)]
    assert fix.utc_time == 12 * 3600 + 35 * 60 + 19
    assert (fix.latitude, fix.longitude) == (pytest.approx(48 + 7.038 / 60), pytest.approx(11 + 31.0 / 60))
    assert (fix.status, fix.quality, fix.satellites, fix.hdop, fix.altitude) == (records.STATUS_FIX, 1, 8, 0.9, 545.4)
    cov, kind = fix.covariance
    assert kind == records.COVARIANCE_TYPE_DIAGONAL_KNOWN and cov[0] == pytest.approx(0.36) \
        and cov[4] == pytest.approx(0.16) and cov[8] == pytest.approx(1.21)
    rmc, vtg = [r for r in out if not isinstance(r, NmeaFix)]
    assert rmc.speed == pytest.approx(22.4 * 1852 / 3600) and rmc.course == 84.4
    assert vtg.speed == pytest.approx(10.2 / 3.6) and vtg.east_north[1] == pytest.approx(10.2 / 3.6 * math.cos(
        math.radians(54.7)))
    assert dec.stats == {"sentences": 4, "fixes": 1, "velocities": 2, "ignored": 2, "void": 0}
    # a GGA without its GST is held until a later epoch (or the end of the file): no covariance
    assert dec.feed(sentence("GPGGA,123520,4807.038,S,01131.000,W,4,08,0.9,545.4,M,46.9,M,,")) == []
    late, = dec.feed(epoch("123521", 48.0, 11.0)[0])
    assert (late.latitude, late.status, late.covariance[1]) == (pytest.approx(-48.1173), records.STATUS_GBAS_FIX,
                                                                records.COVARIANCE_TYPE_UNKNOWN)


def test_corrupted_nmea_sentences_are_refused_with_their_reason_and_change_nothing():
    good = epoch("080000.00", 48.2, 11.6)
    cases = {
        "checksum": [GGA[:-2] + "48", GGA.replace("4807.038", "4807.039")],
        "truncated": [GGA[:40], GGA[:-3], sentence("GPGGA,123519,4807.038,N,01131.000,E,1,08")],
        "out_of_range": [sentence("GPGGA,123519,4867.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,"),   # 67 minutes
                         sentence("GPGGA,123519,9107.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,"),
                         sentence("GPGGA,123519,4807.038,N,18131.000,E,1,08,0.9,545.4,M,46.9,M,,"),
                         sentence("GPGGA,123519,4807.038,N,01131.000,E,11,08,0.9,545.4,M,46.9,M,,"),
                         sentence("GPGST,123519,1.2,0.5,0.3,45.0,-0.4,0.6,1.1")],
        "talker": [sentence("XXGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,")],
        "malformed": ["GPGGA,123519*47", b"$GPGGA,\xff\xfe*00", "$" + "A" * 90 + "*00",
                      sentence("GPGGA,12x519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,")],
    }
    dec = NmeaDecoder()
    assert dec.feed(good[0]) == []   # a fix held: no refusal may release or change it
    assert_refused(dec.feed, cases)
    fix, = dec.feed(good[1])
    assert fix.latitude == pytest.approx(48.2, abs=1e-7) and fix.covariance[0][0] == pytest.approx(0.4 ** 2)
    assert dec.stats["sentences"] == 2 and dec.stats["fixes"] == 1
    assert LineBuffer().feed(b"$GPGGA,1\r\n$GPG") == [b"$GPGGA,1"]


def test_nmea_fixes_of_a_receiver_on_the_track_are_map_matched_to_the_truth():
    """GGA + GST made along the drivers' line, decoded and read by the standard input's GNSS
    reader: the train front's chainage back within centimetres, the GST sigma as its 1-sigma."""
    sc = Scenario.from_yaml(SCENARIO)
    p = sensor_params(spec("dgps_receiver"), {}, sc.vehicle)
    reader, dec = NavSatIngest(p, sc.track), NmeaDecoder()
    proj = sc.track.geodetic.projection()
    for k, s in enumerate((600.0, 1450.0, 3100.0)):
        x, y, _ = sc.track.pose(s)
        lat, lon = proj.to_geodetic(x, y)
        fix, = sum((dec.feed(line) for line in epoch(f"0900{k:02d}.00", lat, lon, sigma=(0.9, 1.2, 2.0))), [])
        pf = reader.fix(fix.gnss_fix(100.0 + k))
        assert pf.position == pytest.approx(s + p["antenna_offset"], abs=0.01)
        assert pf.position_stddev == pytest.approx(1.2)   # the larger horizontal sigma (longitude's: east)
    autonomous, = sum((dec.feed(line) for line in epoch("090010.00", lat, lon, quality=1)), [])
    assert reader.fix(autonomous.gnss_fix(110.0)) is None and reader.stats["autonomous"] == 1


def test_nmea_streams_from_a_udp_port_and_a_serial_device():
    udp = UdpLines("127.0.0.1", 0)
    try:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
            tx.sendto(f"{GGA}\r\n{VTG}\r\n".encode(), ("127.0.0.1", udp.port))
            deadline = time.monotonic() + 2.0
            lines = []
            while not lines and time.monotonic() < deadline:
                lines = udp.read()
        assert lines == [GGA.encode(), VTG.encode()]
        with pytest.raises(StreamError, match="UDP"):
            UdpLines("127.0.0.1", udp.port)   # taken
    finally:
        udp.close()
    master, slave = os.openpty()
    port = SerialLines(os.ttyname(slave), 9600)
    try:
        os.write(master, (GGA + "\r\n" + RMC[:30]).encode())   # a sentence and a half
        deadline, lines = time.monotonic() + 2.0, []
        while not lines and time.monotonic() < deadline:
            lines = port.read()
        assert lines == [GGA.encode()]
        os.write(master, (RMC[30:] + "\r\n").encode())
        deadline, lines = time.monotonic() + 2.0, []
        while not lines and time.monotonic() < deadline:
            lines = port.read()
        assert lines == [RMC.encode()]
    finally:
        port.close()
        os.close(master)
        os.close(slave)
    with pytest.raises(StreamError, match="baud"):
        SerialLines("/dev/null", 1234)


def test_a_replayed_recording_keeps_its_pace_and_restarts_it_where_its_time_runs_back():
    pace = ReplayPace(2.0)
    assert [pace.due(t, 100.0) for t in (50.0, 51.0, 54.0)] == [100.0, 100.5, 102.0]
    assert pace.due(10.0, 103.0) == 103.0 and ReplayPace(0.0).due(7.0, 5.0) == 5.0


@pytest.fixture(scope="module")
def dbc():
    return cantools.database.load_file(str(DBC))


def wheel_frame(dbc, stamp, count, alive, direction=1, status=0) -> CanFrame:
    msg = dbc.get_message_by_name("WHEEL_PULSES")
    return CanFrame(stamp, msg.frame_id, msg.encode({"PulseCount": count % 65536, "Direction": direction,
                                                     "Status": status, "AliveCounter": alive % 16}, strict=False))


def radar_frame(dbc, stamp, speed, alive, quality=95) -> CanFrame:
    msg = dbc.get_message_by_name("RADAR_SPEED")
    return CanFrame(stamp, msg.frame_id, msg.encode({"Speed": speed, "Quality": quality, "AliveCounter": alive % 16},
                                                    strict=False))


def test_can_frames_on_a_virtual_bus_become_wheel_and_radar_speeds(dbc):
    """A pulse generator at 20 m/s (its 16-bit count wrapping) and a radar, sent on python-can's
    virtual bus, received and decoded with the DBC; one wheel frame lost on the bus."""
    geometry = WheelGeometry(60, 0.92)
    dec = CanOdometryDecoder(str(DBC), geometry)
    tx, rx = can.Bus(interface="virtual", channel="tl54"), can.Bus(interface="virtual", channel="tl54")
    sent = []   # the frames' bus times (the virtual bus stamps them with the host's clock)
    try:
        pulses_per_frame = 20.0 * 0.02 / geometry.distance_per_pulse   # 8.3 pulses a frame
        for k in range(50):
            for f in (wheel_frame(dbc, 0.02 * k, 65000 + int(pulses_per_frame * k), k),
                      radar_frame(dbc, 0.02 * k + 0.01, -3.5 if k == 10 else 20.01, k)):
                if k == 20 and f.frame_id == 384:
                    continue   # lost on the bus: the alive counter jumps by two
                tx.send(can.Message(arbitration_id=f.frame_id, data=f.data, is_extended_id=False))
                sent.append(f.stamp)
        out = []
        while (msg := rx.recv(timeout=0.5)) is not None:
            out.append(dec.decode(CanFrame(sent[len(out)], msg.arbitration_id, bytes(msg.data))))
    finally:
        tx.shutdown()
        rx.shutdown()
    wheel = [o.twist for o in out if o is not None and o.device == "wheel"]
    radar = [o.twist for o in out if o is not None and o.device == "radar"]
    assert len(wheel) == 48 and len(radar) == 50 and out[0] is None
    steps = [b.stamp - a.stamp for a, b in zip([None] + wheel, wheel) if a is not None]
    distance = wheel[0].speed * 0.02 + sum(w.speed * dt for w, dt in zip(wheel[1:], steps))
    assert distance == pytest.approx(int(pulses_per_frame * 49) * geometry.distance_per_pulse, abs=1e-9)
    assert wheel[0].speed_variance == pytest.approx(geometry.distance_per_pulse ** 2 / 6 / 0.02 ** 2)
    assert wheel[19].speed == pytest.approx((int(pulses_per_frame * 21) - int(pulses_per_frame * 19))
                                            * geometry.distance_per_pulse / 0.04)
    assert sorted({round(r.speed, 2) for r in radar}) == [-3.5, 20.01]
    assert radar[0].speed_variance == pytest.approx(0.01 ** 2 / 12)
    assert dec.stats == {"frames": 99, "lost": 1, "gaps": 0}


def test_bad_can_frames_are_refused_with_their_reason_and_change_nothing(dbc):
    dec = CanOdometryDecoder(str(DBC), WheelGeometry(60, 0.92), CanLimits(min_quality=50.0, max_age=0.5))
    assert dec.decode(wheel_frame(dbc, 1.00, 100, 0)) is None
    assert dec.decode(radar_frame(dbc, 1.01, 10.0, 0)).twist.speed == 10.0
    good = wheel_frame(dbc, 1.02, 104, 1)
    bad = {
        "unknown_id": [CanFrame(1.02, 0x123, good.data), CanFrame(1.02, good.frame_id, good.data, True)],
        "length": [CanFrame(1.02, good.frame_id, good.data[:6]), CanFrame(1.02, good.frame_id, good.data + b"\0")],
        "out_of_range": [wheel_frame(dbc, 1.02, 104, 1, direction=3), wheel_frame(dbc, 1.02, 104, 1, status=9),
                         radar_frame(dbc, 1.02, 250.0, 1), wheel_frame(dbc, 1.02, 160, 1)],   # 56 pulses: 135 m/s
        "stale": [wheel_frame(dbc, 1.00, 104, 1), wheel_frame(dbc, 1.02, 104, 0),                # old, frozen
                  radar_frame(dbc, 0.3, 10.0, 1)],                                               # 0.72 s behind
        "device_fault": [wheel_frame(dbc, 1.02, 104, 1, status=1)],
        "quality": [radar_frame(dbc, 1.03, 10.0, 1, quality=20)],
        "implausible": [wheel_frame(dbc, 1.02, 104, 1, direction=0)],
    }
    assert_refused(dec.decode, bad)
    w = dec.decode(good).twist   # as if nothing bad had come
    assert w.speed == pytest.approx(4 * math.pi * 0.92 / 60 / 0.02)
    assert dec.stats == {"frames": 3, "lost": 0, "gaps": 0}
    with pytest.raises(ValueError, match="lacks the signals"):
        CanOdometryDecoder(str(DBC), WheelGeometry(60, 0.92), wheel_message="RADAR_SPEED", radar_message="")
    with pytest.raises(ValueError, match="no message"):
        CanOdometryDecoder(str(DBC), WheelGeometry(60, 0.92), wheel_message="PG")


def _diag_values(diags, prefix):
    ours = [s for d in diags for s in d.status if s.name.startswith(prefix)]
    return {kv.key: kv.value for kv in ours[-1].values} if ours else {}


def _reading(diags, prefix) -> bool:
    """Whether the last status of ``prefix`` published on /diagnostics says it is reading its device."""
    ours = [s for d in diags for s in d.status if s.name.startswith(prefix)]
    return bool(ours) and ours[-1].message.startswith("reading")


def test_the_ingest_nodes_publish_navsatfix_odometry_and_twist_over_dds(ros_context, start_node, tmp_path, dbc):
    """nmea_ingest on a UDP port and can_ingest replaying a candump log publish the standard
    messages standard_inputs reads; corrupted sentences and frames are counted, not published."""
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import TwistWithCovarianceStamped
    from nav_msgs.msg import Odometry
    from sensor_msgs.msg import NavSatFix

    log = tmp_path / "odometry.log"
    writer = can.Logger(str(log))
    frames = []
    for k in range(40):   # 0.8 s at 50 Hz: 15 m/s on the wheel, 14.98 m/s on the radar
        frames += [wheel_frame(dbc, 1000.0 + 0.02 * k, int(15.0 * 0.02 * k / (math.pi * 0.92 / 60)), k),
                   radar_frame(dbc, 1000.005 + 0.02 * k, 14.98, k)]
    frames.insert(30, CanFrame(1000.3, 0x7FF, b"\x01\x02"))                        # unknown_id
    frames.insert(50, radar_frame(dbc, 1000.482, 14.98, 15, quality=10))           # quality
    for f in frames:
        writer.on_message_received(can.Message(timestamp=f.stamp, arbitration_id=f.frame_id, data=f.data,
                                               is_extended_id=False))
    writer.stop()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    nmea = start_node("nmea_ingest", "--ros-args", "-p", f"udp.port:={port}", "-p", "fix_topic:=/t54/gnss/fix")
    canin = start_node("can_ingest", "--ros-args", "-p", f"log:={log}", "-p", "rate:=2.0", "-p", "wait_for_subscribers:=1",
                       "-p", "wheel.topic:=/t54/wheel/odometry", "-p", "radar.topic:=/t54/radar/twist")
    node = ros_context.create_node("probe_devices")
    fixes, odoms, twists, diags = [], [], [], []
    node.create_subscription(NavSatFix, "/t54/gnss/fix", fixes.append, 100)
    node.create_subscription(Odometry, "/t54/wheel/odometry", odoms.append, 100)
    node.create_subscription(TwistWithCovarianceStamped, "/t54/radar/twist", twists.append, 100)
    node.create_subscription(DiagnosticArray, "/diagnostics", diags.append, 100)
    try:
        # the UDP port is bound on activate, after the publisher exists: send once the node says
        # it is reading (a datagram sent before is lost, as on any UDP port nobody listens to)
        assert spin_until(node, lambda: _reading(diags, "nmea_ingest") and len(twists) >= 40
                          and len(odoms) >= 39, 30.0), \
            canin.output()[-800:]
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
            lines = epoch("101500.00", 48.2, 11.6) + [GGA[:-2] + "00", GGA[:30]] + epoch("101501.00", 48.2, 11.6001)
            tx.sendto("\r\n".join(lines).encode(), ("127.0.0.1", port))
        assert spin_until(node, lambda: len(fixes) >= 2 and _diag_values(diags, "nmea_ingest").get(
            "rejected/nmea/truncated") == "1" and _diag_values(diags, "can_ingest").get("rejected/can/quality"), 10.0)
        assert [round(f.longitude, 4) for f in fixes] == [11.6, 11.6001]
        assert fixes[0].status.status == 1 and fixes[0].position_covariance[0] == pytest.approx(0.16)
        assert fixes[0].position_covariance_type == NavSatFix.COVARIANCE_TYPE_DIAGONAL_KNOWN
        assert {k: v for k, v in _diag_values(diags, "nmea_ingest").items() if k.startswith("rejected/")} == \
            {"rejected/nmea/checksum": "1", "rejected/nmea/truncated": "1"}
        assert len(odoms) == 39 and len(twists) == 40
        assert sum(o.twist.twist.linear.x for o in odoms) * 0.02 == pytest.approx(15.0 * 0.02 * 39, abs=0.06)
        assert {round(t.twist.twist.linear.x, 2) for t in twists} == {14.98}
        assert {k: v for k, v in _diag_values(diags, "can_ingest").items() if k.startswith("rejected/")} == \
            {"rejected/can/unknown_id": "1", "rejected/can/quality": "1"}
        assert nmea.interrupt() == 0 and canin.interrupt() == 0
    finally:
        node.destroy_node()
