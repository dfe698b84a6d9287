"""tl_bench flood: the live fusion node's output against a flood on one of its inputs.

  tl_bench flood [--rates 0,1000,5000,20000] [--seconds 5] [--invalid]

Starts the fusion node (Doppler and balise inputs, 200 Hz) and a recorder as processes, on a
ROS_DOMAIN_ID of their own with DDS on loopback; publishes Doppler speeds on
``sensors/doppler/speed`` at each rate in turn for ``--seconds`` s (stamped with the wall
clock, like a device): valid ones, or with ``--invalid`` NaN speeds (each refused as ``nan``),
and reads the recorded states and diagnostics: per rate, the states and the fusion's
/diagnostics reports received per second of wall time, how far behind the clock the states
were (median, 95th percentile) and what the node shed (``max_input_rate``,
core/fusion/shedding.py) and refused. The state must keep coming at its rate, and the
diagnostics at 1 Hz, under any input rate, valid or not. Wall-clock figures: run on an idle
machine.
"""
from __future__ import annotations

import argparse
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import NamedTuple

import numpy as np

from . import domains
from .demo import executable, stop

NAMESPACE = "/flood"
PUBLISH_RATE = 200.0   # [Hz] of the fusion's states (its default)
BATCH = 0.01           # [s] between two batches of flood messages


class FloodRow(NamedTuple):
    """One rate of the flood and what the fusion made of it."""

    input_rate: float      # [messages/s] asked
    sent_rate: float       # [messages/s] published
    output_rate: float     # [states/s of wall time]
    lag_median: float      # [s] wall clock at recording - the state's stamp
    lag_p95: float         # [s]
    shed: int              # messages shed (whole run, cumulative at the phase's end)
    refused: int           # messages refused (whole run, cumulative at the phase's end)
    diagnostics_rate: float   # [reports/s of wall time] of the fusion's own /diagnostics status


def _start(exe: str, args: list[str], env: dict, log: Path) -> subprocess.Popen:
    return subprocess.Popen([executable(exe), "--ros-args", "-r", f"__ns:={NAMESPACE}", *args], env=env,
                            stdout=open(log, "w"), stderr=subprocess.STDOUT, start_new_session=True)


def speed_message(cls, t: float, speed: float):
    """A flood's SpeedMeasurement (``cls``) of ``speed`` [m/s], stamped ``t`` [s]."""
    msg = cls(sensor="doppler", unit_id="flood", speed=speed, speed_stddev=0.1)
    msg.header.stamp.sec, msg.header.stamp.nanosec = int(t), int((t % 1.0) * 1e9)
    return msg


def publish_flood(pub, message, rate: float, seconds: float, spin=None) -> tuple[int, float, float]:
    """Publish ``message(t)`` (t: the wall clock [s], its stamp) ``rate`` times a second (inf: as
    fast as the publisher goes) for ``seconds`` [s], in batches BATCH s apart; ``spin()`` after
    each batch. (messages sent, wall clock [s] at the start and at the end.)"""
    t0, sent = time.time(), 0
    next_batch = time.monotonic()
    while time.time() - t0 < seconds:
        due = int(rate * (time.time() - t0)) - sent if math.isfinite(rate) else 50
        for _ in range(max(due, 0)):
            pub.publish(message(time.time()))
            sent += 1
        if spin is not None:
            spin()
        if math.isfinite(rate):
            next_batch += BATCH
            time.sleep(max(0.0, next_batch - time.monotonic()))
    return sent, t0, time.time()


def run(rates: list[float], seconds: float, work: Path, max_input_rate: float = 1000.0,
        invalid: bool = False) -> list[FloodRow]:
    """The flood at each of ``rates`` [messages/s] for ``seconds`` [s] each, the fusion's
    ``max_input_rate`` as given; ``invalid``: NaN speeds, which the fusion refuses; ``work``:
    the bag and the nodes' logs."""
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from train_localization_msgs.msg import SpeedMeasurement
    from ..core.bagio import read_bag
    from ..nodes.common import STREAM_QOS

    lease = domains.lease(10, 99)
    env = domains.node_env(lease.domain)
    bag = work / "flood.mcap"
    fusion = _start("fusion", ["-p", "sensors:=[doppler, eurobalise]", "-p", f"publish_rate:={PUBLISH_RATE}",
                               "-p", f"max_input_rate:={max_input_rate}"], env, work / "fusion.log")
    recorder = _start("recorder", ["-p", f"output:={bag}", "-p", "topics:=[localization/state, /diagnostics]"],
                      env, work / "recorder.log")
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = env["ROS_AUTOMATIC_DISCOVERY_RANGE"]   # this process's own node
    context = Context()
    context.init(domain_id=lease.domain)
    node = rclpy.create_node("flood", namespace=NAMESPACE, context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    pub = node.create_publisher(SpeedMeasurement, "sensors/doppler/speed", STREAM_QOS)
    phases = []
    speed = math.nan if invalid else 20.0   # [m/s]
    try:
        deadline = time.monotonic() + 60.0
        while pub.get_subscription_count() < 1 and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.1)
        if pub.get_subscription_count() < 1:
            raise RuntimeError(f"the fusion did not subscribe within 60 s (log: {work / 'fusion.log'})")
        time.sleep(2.0)   # the recorder discovers the state topic
        for rate in rates:
            sent, t0, _ = publish_flood(pub, lambda t: speed_message(SpeedMeasurement, t, speed), rate, seconds)
            phases.append((rate, sent / seconds, t0, t0 + seconds))
            time.sleep(1.0)
    finally:
        node.destroy_node()
        context.try_shutdown()
        stop(recorder)
        stop(fusion)
        lease.release()
    states, reports = [], []   # (wall time [s], stamp [s]); (wall time [s], shed, refused)
    for topic, _, t_ns, msg in read_bag(bag):
        if topic.endswith("localization/state"):
            states.append((t_ns * 1e-9, msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec))
        elif topic == "/diagnostics":
            for st in msg.status:
                if st.name.endswith(": fusion"):
                    shed = sum(int(kv.value) for kv in st.values if kv.key.startswith("shed/"))
                    refused = sum(int(kv.value) for kv in st.values if kv.key.startswith("rejected/"))
                    reports.append((t_ns * 1e-9, shed, refused))
    logged = np.array(states) if states else np.zeros((0, 2))
    rows = []
    for rate, sent_rate, t0, t1 in phases:
        inside = logged[(logged[:, 0] >= t0) & (logged[:, 0] < t1)] if len(logged) else logged
        lag = inside[:, 0] - inside[:, 1] if len(inside) else np.array([np.nan])
        shed = max((n for t, n, _ in reports if t <= t1 + 1.0), default=0)
        refused = max((n for t, _, n in reports if t <= t1 + 1.0), default=0)
        diagnostics = sum(1 for t, _, _ in reports if t0 <= t < t1)
        rows.append(FloodRow(rate, sent_rate, len(inside) / (t1 - t0), float(np.median(lag)),
                             float(np.percentile(lag, 95)), shed, refused, diagnostics / (t1 - t0)))
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rates", default="0,1000,5000,20000", help="flood rates [messages/s], comma-separated")
    ap.add_argument("--seconds", type=float, default=5.0, help="seconds of flood per rate (5)")
    ap.add_argument("--max-input-rate", type=float, default=1000.0,
                    help="the fusion's max_input_rate [messages/s] (1000; 1e6: no shedding, to compare)")
    ap.add_argument("--invalid", action="store_true", help="flood with NaN speeds (refused as nan) instead of "
                                                           "valid ones")
    args = ap.parse_args(argv)
    rates = [float(r) for r in args.rates.split(",") if r.strip()]
    with tempfile.TemporaryDirectory(prefix="tl_flood_") as tmp:
        rows = run(rates, args.seconds, Path(tmp), args.max_input_rate, args.invalid)
    print(f"fusion at {PUBLISH_RATE:g} Hz, max_input_rate {args.max_input_rate:g}/s, a flood of "
          f"{'invalid (NaN)' if args.invalid else 'valid'} Doppler speeds; {os.cpu_count()} CPU cores")
    print(f"{'asked /s':>9s} {'sent /s':>8s} {'states /s':>10s} {'diag /s':>8s} {'lag p50 s':>10s} {'lag p95 s':>10s} "
          f"{'shed':>8s} {'refused':>8s}")
    for r in rows:
        print(f"{r.input_rate:9.0f} {r.sent_rate:8.0f} {r.output_rate:10.1f} {r.diagnostics_rate:8.2f} "
              f"{r.lag_median:10.4f} {r.lag_p95:10.4f} {r.shed:8d} {r.refused:8d}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
