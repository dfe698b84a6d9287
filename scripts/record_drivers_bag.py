#!/usr/bin/env python3
"""Record bags/osm_drivers.mcap: what a train whose devices speak standard protocols records,
with its ground truth, on a track imported from OpenStreetMap.

  python scripts/record_drivers_bag.py [--scenario S] [--bag B] [--nmea N]
  python -m train_localization.tools.make_bags --only osm_drivers --thresholds-only

The scenario (config/scenario_osm_drivers.yaml) drives the project's sensor models with its seed
(the same scenario gives the same bytes); their output becomes what the devices send:

* the GNSS receiver (the DGPS model's solution: white noise, multipath, HDOP, satellites) as an
  NMEA 0183 log, GGA + GST + RMC each epoch, written with pynmea2 to ``--nmea``
  (test/fixtures/osm_drivers.nmea) with the corrupt sentences of CORRUPT (a serial line's bit
  errors and cut sentences); the log read back through the NMEA decoder (core/ingest/nmea.py
  decode_log, as nmea_ingest reads a file: the corrupt sentences refused and counted) becomes
  sensor_msgs/NavSatFix on /gnss/fix, stamped with the epoch's GNSS time (its UTC less
  UTC_START: the bag's time line, as nmea_navsat_driver's use_GNSS_time), logged LATENCY later;
* the IMU (the gyro model's rate samples, 100 Hz; the specific force of the truth's
  acceleration and gravity) as sensor_msgs/Imu on /imu/data;
* the wheel odometer (the wheel pulse generator's decoded speed, 20 Hz) as nav_msgs/Odometry
  on /wheel/odometry;
* BAD_MESSAGES: an Imu with a NaN rate and an Odometry stamped back in time (a driver's clock
  step), which the standard inputs refuse;
* the ground truth on /train/ground_truth/state (in the fused state's frame: on a network the
  section and its chainage) and the scenario on /train/scenario, as in every bag of bags/
  (scripts/score_bag.py and tl_replay read them).
"""
from __future__ import annotations

import argparse
import datetime as dt
import math
import sys
from pathlib import Path

import numpy as np
import pynmea2

from train_localization.core import convert
from train_localization.core.bagio import BagWriter, typestore, typestore_classes
from train_localization.core.ingest.navsat import anchor_of
from train_localization.core.ingest.nmea import KNOT, NmeaFix, decode_log
from train_localization.core.offline import SCENARIO_TOPIC, TRUTH_TOPIC, string_message
from train_localization.core.pipeline import sensor_pipelines
from train_localization.core.scenario import Scenario

ROOT = Path(__file__).resolve().parents[1]
UTC_START = dt.datetime(2026, 3, 12, 10, 15, 0, tzinfo=dt.timezone.utc)   # the recording's t = 0
LATENCY = 0.05          # [s] from a GNSS epoch to its NavSatFix on the bus
GRAVITY = 9.80665       # [m/s^2]
ALTITUDE, GEOID = 512.3, 47.0   # [m] the antenna above mean sea level, the geoid above the ellipsoid
# epoch index -> (sentence, corruption): a digit flipped on the line (the checksum no longer
# matches), a checksum garbled, a sentence cut off where the receiver's buffer overflowed
CORRUPT = {40: ("GGA", "flip"), 150: ("GST", "checksum"), 250: ("RMC", "flip"),
           100: ("GGA", "cut"), 200: ("GST", "cut")}
# (topic, stamp [s], what is wrong): messages no healthy driver sends, refused by the standard inputs
BAD_MESSAGES = (("/imu/data", 30.0025, "nan"), ("/wheel/odometry", 45.0, "back"))
FIX_TOPIC, IMU_TOPIC, ODOMETRY_TOPIC = "/gnss/fix", "/imu/data", "/wheel/odometry"
MC = typestore_classes()


def _ddmm(value: float, degree_digits: int) -> str:
    d = int(abs(value))
    return f"{d:0{degree_digits}d}{(abs(value) - d) * 60.0:09.6f}"


def _utc(t: float) -> tuple[str, str]:
    """(hhmmss.ss, ddmmyy) of the recording's time t [s]."""
    when = UTC_START + dt.timedelta(seconds=round(t, 2))
    return when.strftime("%H%M%S.") + f"{when.microsecond // 10000:02d}", when.strftime("%d%m%y")


def epoch_sentences(t: float, lat: float, lon: float, quality: int, satellites: int, hdop: float,
                    sigma: float, speed: float, course: float) -> dict[str, str]:
    """A receiver's GGA, GST and RMC of one epoch (pynmea2 renders them with their checksums)."""
    hms, date = _utc(t)
    ns, ew = "N" if lat >= 0 else "S", "E" if lon >= 0 else "W"
    lat_f, lon_f = _ddmm(lat, 2), _ddmm(lon, 3)
    return {
        "GGA": pynmea2.GGA("GN", "GGA", (hms, lat_f, ns, lon_f, ew, str(quality), f"{satellites:02d}", f"{hdop:.1f}",
                                         f"{ALTITUDE:.1f}", "M", f"{GEOID:.1f}", "M", "1.0", "0120")).render(),
        "GST": pynmea2.GST("GN", "GST", (hms, f"{sigma:.2f}", f"{sigma:.2f}", f"{sigma:.2f}", "0.0", f"{sigma:.2f}",
                                         f"{sigma:.2f}", f"{2.0 * sigma:.2f}")).render(),
        "RMC": pynmea2.RMC("GN", "RMC", (hms, "A", lat_f, ns, lon_f, ew, f"{speed / KNOT:.2f}", f"{course:.1f}", date,
                                         "", "", "D")).render(),
    }


def corrupt(sentence: str, how: str) -> str:
    if how == "flip":   # the last digit before the checksum changed
        i = max(k for k, c in enumerate(sentence[:-3]) if c.isdigit())
        return sentence[:i] + str((int(sentence[i]) + 1) % 10) + sentence[i + 1:]
    if how == "checksum":
        return sentence[:-2] + f"{(int(sentence[-2:], 16) + 1) % 256:02X}"
    return sentence[: len(sentence) // 2]   # cut


def _header(t: float, frame_id: str):
    return MC.header(t, frame_id)


def _vector(x: float = 0.0, y: float = 0.0, z: float = 0.0):
    return typestore().types["geometry_msgs/msg/Vector3"](x=float(x), y=float(y), z=float(z))


def navsat_fix(fix: NmeaFix, stamp: float):
    """The sensor_msgs/NavSatFix of a decoded epoch, as nmea_ingest publishes it."""
    t = typestore().types
    cov, kind = fix.covariance
    return t["sensor_msgs/msg/NavSatFix"](
        header=_header(stamp, "gnss"), status=t["sensor_msgs/msg/NavSatStatus"](status=fix.status, service=1),
        latitude=fix.latitude, longitude=fix.longitude, altitude=fix.altitude,
        position_covariance=np.array(cov, dtype=float), position_covariance_type=kind)


def imu_sample(stamp: float, yaw_rate: float, rate_variance: float, acceleration: float):
    t = typestore().types
    no_orientation = np.zeros(9)
    no_orientation[0] = -1.0   # REP-145: no orientation estimate
    return t["sensor_msgs/msg/Imu"](
        header=_header(stamp, "imu"), orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
        orientation_covariance=no_orientation, angular_velocity=_vector(z=yaw_rate),
        angular_velocity_covariance=np.diag([rate_variance] * 3).ravel(),
        linear_acceleration=_vector(x=acceleration, z=GRAVITY),
        linear_acceleration_covariance=np.diag([1e-4] * 3).ravel())


def odometry(stamp: float, distance: float, speed: float, speed_variance: float):
    t = typestore().types
    pose_cov, twist_cov = np.zeros(36), np.zeros(36)
    twist_cov[0] = speed_variance
    pose = t["geometry_msgs/msg/Pose"](position=t["geometry_msgs/msg/Point"](x=distance, y=0.0, z=0.0),
                                       orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0))
    twist = t["geometry_msgs/msg/Twist"](linear=_vector(x=speed), angular=_vector())
    return t["nav_msgs/msg/Odometry"](
        header=_header(stamp, "odom"), child_frame_id="base_link",
        pose=t["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=pose_cov),
        twist=t["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=twist_cov))


def epoch_time(fix: NmeaFix) -> float:
    """The recording's time [s] of a fix's UTC time of day."""
    start = UTC_START.hour * 3600.0 + UTC_START.minute * 60.0 + UTC_START.second
    return round(fix.utc_time - start, 6)


def record(scenario: Scenario, bag: Path, nmea: Path) -> dict:
    """Write the NMEA log and the bag; returns what they hold (counts)."""
    pipes = {p.spec.node: p for p in sensor_pipelines(scenario)}
    traj, track = scenario.trajectory(), scenario.track
    projection = anchor_of(track).projection()
    dgps, gyro, wheel = (pipes[n] for n in ("dgps_receiver", "gyro", "wheel_sensor"))
    sigma = math.hypot(dgps.params["white_sigma"], dgps.params["multipath_sigma"])   # the receiver's own estimate
    rate_variance = gyro.params["noise_density"] ** 2 * gyro.sample_rate
    messages = [(0, SCENARIO_TOPIC, string_message(scenario.to_yaml()))]   # (log time [ns], topic, message)
    lines, distance, epoch = [], 0.0, 0
    for k in range(int(round(scenario.duration * scenario.truth_rate)) + 1):
        t = convert.canonical(k / scenario.truth_rate)
        state = traj.state_at(t)
        messages.append((convert.sec_to_ns(t), TRUTH_TOPIC, convert.truth_to_msg(MC, state, track)))
        for block in dgps.on_truth(state):
            for ts, (x, y, quality, satellites, hdop) in zip(block.times(), block.data.astype(float)):
                lat, lon = projection.to_geodetic(x, y)
                truth = traj.state_at(float(ts))
                heading = track.pose(truth.position)[2]
                course = math.degrees(math.pi / 2 - heading) % 360.0
                sentences = epoch_sentences(float(ts), lat, lon, int(quality), int(satellites), hdop, sigma,
                                            abs(truth.speed), course)
                kind, how = CORRUPT.get(epoch, (None, None))
                lines += [corrupt(s, how) if name == kind else s for name, s in sentences.items()]
                epoch += 1
        for block in gyro.on_truth(state):
            for ts, (rate,) in zip(block.times(), block.data.astype(float)):
                ts = round(float(ts), 6)
                messages.append((convert.sec_to_ns(ts), IMU_TOPIC,
                                 imu_sample(ts, rate, rate_variance, traj.state_at(ts).acceleration)))
        for block in wheel.on_truth(state):
            for m in wheel.on_block(block):
                distance += m.distance
                messages.append((convert.sec_to_ns(m.stamp), ODOMETRY_TOPIC,
                                 odometry(m.stamp, distance, m.speed, 0.02 ** 2)))
    for topic, stamp, what in BAD_MESSAGES:
        if what == "nan":
            messages.append((convert.sec_to_ns(stamp), topic, imu_sample(stamp, math.nan, rate_variance, 0.0)))
        else:   # stamped 0.5 s back
            messages.append((convert.sec_to_ns(stamp), topic, odometry(stamp - 0.5, distance, 0.0, 0.02 ** 2)))
    nmea.parent.mkdir(parents=True, exist_ok=True)
    nmea.write_text("".join(f"{line}\r\n" for line in lines), encoding="ascii")
    records, refused = decode_log(nmea.read_bytes().splitlines())
    fixes = [r for r in records if isinstance(r, NmeaFix)]
    for fix in fixes:
        stamp = epoch_time(fix)
        messages.append((convert.sec_to_ns(stamp + LATENCY), FIX_TOPIC, navsat_fix(fix, stamp)))
    messages.sort(key=lambda m: m[0])   # stable: a message logged with another keeps its place
    with BagWriter(bag) as writer:
        for t_ns, topic, msg in messages:
            writer.write(topic, msg, t_ns)
        counts = dict(writer.counts)
    return {"epochs": epoch, "sentences": len(lines), "fixes": len(fixes), "refused": refused, "messages": counts}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario", default=str(ROOT / "config" / "scenario_osm_drivers.yaml"))
    ap.add_argument("--bag", type=Path, default=ROOT / "bags" / "osm_drivers.mcap")
    ap.add_argument("--nmea", type=Path, default=ROOT / "test" / "fixtures" / "osm_drivers.nmea")
    args = ap.parse_args(argv)
    out = record(Scenario.from_yaml(args.scenario), args.bag, args.nmea)
    print(f"{args.nmea}: {out['sentences']} sentences of {out['epochs']} epochs, refused {out['refused']}, "
          f"{out['fixes']} fixes")
    print(f"{args.bag}: {args.bag.stat().st_size / 1e6:.2f} MB, {out['messages']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
