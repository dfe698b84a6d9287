"""What every node shares: start-up and shutdown, QoS, diagnostics, parameters.

QoS (docs/integration.md): measurement and raw streams are published RELIABLE with a
deep history so that a recorder gets every message; our own subscribers use the
same profile. A subscriber that prefers the sensor-data profile (best effort) is
compatible with these publishers. State and occupancy topics that a late joiner
needs are reliable + transient-local: the fused state with depth 1 (a late joiner's first
message is the current state), the section occupancy with the depth of all sections.
"""
from __future__ import annotations

import gc
import logging
import math
import os
import signal
import sys
import time
from collections import Counter

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException
from rclpy.lifecycle import LifecycleNode, TransitionCallbackReturn
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from ..core.convert import MsgClasses
from ..core.sensors.base import out_of_limits
from ..core.scenario import ScenarioError
from ..core.track import TrackError
from ..core.signals import InputRejected
from . import exit_guard

STREAM_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.VOLATILE)
LATCHED_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
# the current fused state for late joiners: only the latest is kept (a subscriber that wants
# the stream subscribes reliable with a deep queue, as the recorder does)
STATE_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.TRANSIENT_LOCAL)
CLOCK_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.VOLATILE)


def rclpy_classes() -> MsgClasses:
    """MsgClasses backed by the generated rclpy message modules."""
    from builtin_interfaces.msg import Time
    from geometry_msgs.msg import AccelWithCovariance, AccelWithCovarianceStamped
    from std_msgs.msg import Header
    from train_localization_msgs import msg as m

    def array(values: np.ndarray, kind: str):
        return np.ascontiguousarray(values, dtype=np.float32 if kind == "float32" else np.float64)

    def accel_body(x: float, variance: float):
        body = AccelWithCovariance()
        body.accel.linear.x = x
        body.covariance[0] = variance
        return body

    return MsgClasses(Time=Time, Header=Header, TrainState=m.TrainState, RawBlock=m.RawBlock,
                      PositionFix=m.PositionFix, SpeedMeasurement=m.SpeedMeasurement,
                      DistanceIncrement=m.DistanceIncrement, SectionState=m.SectionState,
                      SectionOccupancy=m.SectionOccupancy, TrackHypothesis=m.TrackHypothesis,
                      TrackHypotheses=m.TrackHypotheses, SwitchPositions=m.SwitchPositions, YawRate=m.YawRate,
                      array=array, AccelWithCovarianceStamped=AccelWithCovarianceStamped, accel_body=accel_body)


MAX_ERROR_LENGTH = 256   # characters of the last refusal a node republishes on /diagnostics
LOG_PERIOD = 1.0         # [s] between two lines a node logs of the input it refuses
REPORT_SLACK = 0.05      # [periods] a /diagnostics report may come before its time (timer jitter)


class Diagnostics:
    """Counts accepted / rejected input by reason and publishes /diagnostics at 1 Hz.

    Every rejection is also logged (throttled) with its reason, so bad input is
    visible without crashing anything.
    """

    def __init__(self, node: Node, name: str, period: float = 1.0):
        self.node = node
        self.name = f"{node.get_name()}: {name}"
        self.accepted: Counter[str] = Counter()
        self.rejected: Counter[str] = Counter()
        self.values: dict[str, str] = {}
        self.last_error = ""
        self.level = 0  # 0 OK, 1 WARN, 2 ERROR, 3 STALE (diagnostic_msgs/DiagnosticStatus)
        self.message = "starting"
        # conditions that make the status at least WARN, each a line appended to the message
        # (an input gone): the node sets them before each report (``extra``)
        self.warnings: list[str] = []
        self._extra = None
        self.clock = None   # optional: () -> stamp [s] of the reports (default: the node clock)
        self.period = period   # [s]
        self._logged_at = -math.inf   # monotonic clock [s] of the last refusal logged
        self.pub = node.create_publisher(DiagnosticArray, "/diagnostics", 10)
        # the reports are due on the timer's schedule (the steady clock is the monotonic one)
        self._next_report = time.monotonic() + period
        node.create_timer(period, self._on_timer, clock=steady_clock())  # also before /clock runs

    def accept(self, stream: str, n: int = 1) -> None:
        self.accepted[stream] += n

    def reject(self, stream: str, reason: str, message: str) -> None:
        self.rejected[f"{stream}/{reason}"] += 1
        self.last_error = f"{stream}: {message}"[:MAX_ERROR_LENGTH]   # echoed every second: bounded
        now = time.monotonic()
        if now - self._logged_at >= LOG_PERIOD:
            # throttled here: rclpy's own throttle costs about 0.4 ms a call (it inspects the
            # caller's frame), which a flood of refused messages pays at every one
            self._logged_at = now
            self.node.get_logger().warn(f"rejected input on {self.last_error}")

    def publish_if_due(self, now: float) -> None:
        """Publish the report that is due (``now``: the monotonic clock [s]), once a period on the
        timer's schedule: from the timer, and from the input's callbacks of a node whose timers
        wait behind a stream of input (the timer, served late, then finds nothing due)."""
        if now < self._next_report - REPORT_SLACK * self.period:
            return
        while self._next_report <= now + REPORT_SLACK * self.period:
            self._next_report += self.period
        self.publish()

    def _on_timer(self) -> None:
        self.publish_if_due(time.monotonic())

    def set_status(self, level: int, message: str) -> None:
        self.level, self.message = level, message

    def extra(self, statuses) -> None:
        """``statuses()``: further DiagnosticStatus entries published with this one (one per
        input, as diagnostic_updater's per-topic tasks); called first, on the wall clock, so
        it may also update this node's own status; None: none."""
        self._extra = statuses

    def publish(self) -> None:
        extra = self._extra() if self._extra else []   # first: it may update this node's own status
        status = DiagnosticStatus(name=self.name, hardware_id=self.node.get_fully_qualified_name())
        level = max(self.level, 1) if self.warnings or self.rejected else self.level
        message = "; ".join([self.message] + self.warnings)
        status.level = bytes([level])
        status.message = message if not self.rejected else f"{message}; {sum(self.rejected.values())} inputs rejected"
        kv = [KeyValue(key=f"accepted/{k}", value=str(v)) for k, v in sorted(self.accepted.items())]
        kv += [KeyValue(key=f"rejected/{k}", value=str(v)) for k, v in sorted(self.rejected.items())]
        kv += [KeyValue(key=k, value=v) for k, v in sorted(self.values.items())]
        if self.last_error:
            kv.append(KeyValue(key="last_error", value=self.last_error))
        status.values = kv
        arr = DiagnosticArray(status=[status] + extra)
        if self.clock is not None:   # a node that makes the simulated time stamps in it too
            arr.header.stamp.sec, arr.header.stamp.nanosec = divmod(int(round(self.clock() * 1e9)), 1_000_000_000)
        else:
            arr.header.stamp = self.node.get_clock().now().to_msg()
        self.pub.publish(arr)


def steady_clock():
    """A wall (steady) clock for timers that must run whatever use_sim_time says."""
    from rclpy.clock import Clock, ClockType
    return Clock(clock_type=ClockType.STEADY_TIME)


class ConfigurationError(ValueError):
    """A parameter or file the node cannot start with: reported in one line, exit code 2."""


def declare(node: Node, name: str, default, description: str = "", read_only: bool = False,
            limits: tuple | None = None):
    """Declare a parameter with a description and return its value.

    A double parameter also takes an integer (``-p rate:=2``): it is declared with dynamic
    typing and converted; anything else raises ConfigurationError naming the parameter.
    ``read_only``: read at start-up only, so ``ros2 param set`` refuses to change it.
    ``limits`` (lo, hi): the inclusive range of a number, in the descriptor (``ros2 param
    describe`` shows it, ``ros2 param set`` beyond it is refused) and checked here. A NaN
    default is a value too (a parameter's 'not set', e.g. the wheel's diameter_error): its
    range is then in the description only (rclpy's range check refuses NaN)."""
    from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
    if node.has_parameter(name):   # declared before configure (ManagedNode.predeclare), or configured again
        return _read_declared(node, name, default, read_only, limits)
    desc = ParameterDescriptor(description=description, read_only=read_only)
    if limits is not None:
        lo, hi = limits
        desc.description += f" [{lo:g} .. {hi:g}]"
        if isinstance(default, float):
            if not math.isnan(default):
                desc.floating_point_range = [FloatingPointRange(from_value=float(lo), to_value=float(hi), step=0.0)]
        else:
            desc.integer_range = [IntegerRange(from_value=int(lo), to_value=int(hi), step=1)]
    if isinstance(default, float):
        desc.dynamic_typing = True
        desc.read_only = False       # until an integer given is stored as the double it means
        value = node.declare_parameter(name, default, desc).value
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigurationError(f"parameter {name!r} must be a number, got {value!r}")
        value = float(value)
        _double_parameters(node).add(name)
        node.set_parameters([Parameter(name, Parameter.Type.DOUBLE, value)])
        if read_only:   # a copy: the node keeps the declared descriptor object itself
            node.set_descriptor(name, ParameterDescriptor(
                name=name, type=desc.type, description=desc.description, read_only=True, dynamic_typing=True,
                floating_point_range=desc.floating_point_range))
    else:
        value = node.declare_parameter(name, default, desc).value
    why = out_of_limits(name, value, limits, default)
    if why:
        raise ConfigurationError(why)
    return value


def _read_declared(node: Node, name: str, default, read_only: bool, limits: tuple | None):
    """The value of a parameter declared already. Declared before configure by a managed node
    and not given by the user since, it takes ``default`` (the run-time one, e.g. the
    scenario's); ``read_only``: from now on (a manager's sets before configure are over)."""
    from rcl_interfaces.msg import ParameterDescriptor
    given = getattr(node, "_given", None)
    if given is not None and name not in given and name in node._predeclared:
        value = float(default) if isinstance(default, float) else default
        if node.get_parameter(name).value != value and not _both_nan(node.get_parameter(name).value, value):
            node._quiet = True
            try:
                result = node.set_parameters([Parameter(name, value=value)])[0]
            finally:
                node._quiet = False
            if not result.successful:
                raise ConfigurationError(f"parameter {name!r}: {result.reason}")
    value = node.get_parameter(name).value
    d = node.describe_parameter(name)
    if read_only and not d.read_only:
        node.set_descriptor(name, ParameterDescriptor(
            name=name, type=d.type, description=d.description, read_only=True, dynamic_typing=d.dynamic_typing,
            floating_point_range=d.floating_point_range, integer_range=d.integer_range))
    why = out_of_limits(name, value, limits, default)
    if why:
        raise ConfigurationError(why)
    return float(value) if isinstance(default, float) else value


def _both_nan(a, b) -> bool:
    return isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b)


def declare_params(node: Node, params: dict, read_only: bool = True) -> dict:
    """Every core Param of ``params`` declared (read-only unless told) with its description and
    range; name -> value."""
    return {name: declare(node, name, p.default, p.description, read_only=read_only, limits=p.limits)
            for name, p in params.items()}


_TABLE_DEFAULT = object()


def declare_param(node: Node, params: dict, name: str, default=_TABLE_DEFAULT, read_only: bool = True):
    """Parameter ``name`` of a node's table ``params`` (name -> core Param: the node's parameters,
    which tools/docs.py writes into its example params file) declared and its value returned;
    ``default``: a run-time default in place of the table's (e.g. the scenario's)."""
    p = params[name]
    return declare(node, name, p.default if default is _TABLE_DEFAULT else default, p.description,
                   read_only=read_only, limits=p.limits)


def _double_parameters(node: Node) -> set:
    """The node's double parameters (declared from a float default, dynamically typed so that
    ``-p rate:=2`` is taken): an integer set at run time is stored as the double it means (a
    pre-set callback), so that the parameter reads back as a double."""
    names = getattr(node, "_tl_double_parameters", None)
    if names is None:
        names = node._tl_double_parameters = set()

        def as_double(params: list) -> list:
            return [Parameter(p.name, Parameter.Type.DOUBLE, float(p.value))
                    if p.name in names and p.type_ == Parameter.Type.INTEGER else p for p in params]
        node.add_pre_set_parameters_callback(as_double)
    return names


# what a user's parameters or files can get wrong: one line, exit code 2 (or a failed configure)
CONFIG_ERRORS = (ConfigurationError, ScenarioError, TrackError, ParameterException, FileNotFoundError)


class ManagedNode(LifecycleNode):
    """A lifecycle node whose ``managed`` parameter decides who drives it: false (the plain
    executable) configures and activates it at start (``start``); true waits for a lifecycle
    manager. Subclasses implement ``_configure`` (raise CONFIG_ERRORS for bad input: the
    configure transition then fails with the reason logged, the node stays up) and the
    other transitions; the subscriptions they make on activate go into ``_subs``, which
    deactivate removes."""

    def __init__(self, node_name: str, diag_name: str):
        super().__init__(node_name)
        self._managed = declare(self, "managed", False, "true: wait for lifecycle transitions (configure, "
                                "activate) from a manager; false: configure and activate at start", read_only=True)
        self.diag = Diagnostics(self, diag_name)
        self.diag.set_status(1, "unconfigured")
        self._config_error = ""
        self._subs: list = []   # subscriptions made on activate
        self._predeclared: set[str] = set()   # declared before configure (managed), writable until then
        self._given: set[str] | None = None   # of those, the ones the user gave (overrides, sets)
        self._quiet = False                   # a set of the node's own: not the user's

    def predeclare(self, params: dict) -> None:
        """Managed: declare ``params`` (name -> core Param) now, writable, so that a manager sees
        them (list_parameters) and may set them before configure; configure reads them (one the
        user has not given takes its run-time default, e.g. the scenario's) and makes them
        read-only. An empty list has no parameter type (left to configure); a value given
        beyond its range is left to configure too (its transition fails in one line, the node
        stays up). Unmanaged: nothing (configure follows at once)."""
        if not self._managed:
            return
        if self._given is None:
            self._given = set()
            self.add_post_set_parameters_callback(self._note_given)
        self._quiet = True
        try:
            for name, p in params.items():
                if self.has_parameter(name) or (isinstance(p.default, list) and not p.default):
                    continue
                try:
                    declare(self, name, p.default, p.description, limits=p.limits)
                except CONFIG_ERRORS:
                    if self.has_parameter(name):
                        self.undeclare_parameter(name)
                    continue
                self._predeclared.add(name)
                if name in self._parameter_overrides:
                    self._given.add(name)
        finally:
            self._quiet = False

    def _note_given(self, params: list) -> None:
        if not self._quiet:
            self._given.update(p.name for p in params)

    def start(self) -> None:
        """Configure and activate now unless managed; ConfigurationError if configuring fails."""
        if self._managed:
            return
        if self.trigger_configure() != TransitionCallbackReturn.SUCCESS:
            raise ConfigurationError(self._config_error or "configuration failed")
        self.trigger_activate()

    def _configure(self) -> None:
        raise NotImplementedError

    def on_configure(self, state) -> TransitionCallbackReturn:
        try:
            self._configure()
        except CONFIG_ERRORS + (ValueError,) as exc:
            self._config_error = f"{type(exc).__name__}: {exc}"
            self.get_logger().error(f"configure failed: {self._config_error}")
            return TransitionCallbackReturn.FAILURE
        self.diag.set_status(1, "inactive (configured)")
        return TransitionCallbackReturn.SUCCESS

    def on_deactivate(self, state) -> TransitionCallbackReturn:
        for sub in self._subs:
            self.destroy_subscription(sub)
        self._subs = []
        self.diag.set_status(1, "inactive (deactivated)")
        return super().on_deactivate(state)



class PollingNode(ManagedNode):
    """A managed node that reads a device (a port, a bus, a file) on a timer: ``_open`` opens it
    on activate (OSError or ValueError in one line: the transition fails, the status says why),
    ``on_timer`` polls it every ``poll_period`` [s], ``_close`` releases it on deactivate and at
    the end (``close``). Unmanaged, a device that cannot be opened stops the node in one line."""

    poll_period = 0.01
    _open_error = ""

    def start(self) -> None:
        super().start()
        if not self._managed and self._open_error:
            raise ConfigurationError(self._open_error)

    def _open(self) -> None:
        raise NotImplementedError

    def _close(self) -> None:
        raise NotImplementedError

    def on_timer(self) -> None:
        raise NotImplementedError

    def on_activate(self, state) -> TransitionCallbackReturn:
        try:
            self._open()
        except (OSError, ValueError) as exc:
            why = self._open_error = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            self.get_logger().error(why)
            self.diag.set_status(2, why)
            return TransitionCallbackReturn.FAILURE
        self._open_error = ""
        self._timer = self.create_timer(self.poll_period, self.on_timer)
        self.diag.set_status(0, "reading")
        return super().on_activate(state)

    def on_deactivate(self, state) -> TransitionCallbackReturn:
        self.close()
        return super().on_deactivate(state)

    def close(self) -> None:
        if getattr(self, "_timer", None) is not None:
            self.destroy_timer(self._timer)
            self._timer = None
        self._close()


def required_scenario(node: Node, params: dict, needed: str):
    """The scenario of the read-only parameter ``scenario`` (of the node's table ``params``); a
    node that cannot run without one stops in one line naming what it ``needed``."""
    from ..core.scenario import Scenario
    path = declare_param(node, params, "scenario")
    if not path:
        raise ConfigurationError(f"parameter 'scenario' is required ({needed})")
    return Scenario.from_yaml(path)

SWITCH_TOPIC = "interlocking/switches"   # SwitchPositions of a train on a network (latched)


def switch_positions(diag: "Diagnostics", msg, network) -> dict[str, str] | None:
    """The interlocking's report (switch -> "B1"/"B2"/"") for the switches of ``network``; None
    for a report refused (malformed, an unknown switch), counted in ``diag``."""
    from ..core.convert import network_switch_positions
    try:
        positions = network_switch_positions(msg, network)
    except InputRejected as exc:
        diag.reject(SWITCH_TOPIC, exc.reason, str(exc))
        return None
    diag.accept(SWITCH_TOPIC)
    return positions


def now_sec(node: Node) -> float:
    return node.get_clock().now().nanoseconds * 1e-9


# default of the nodes' parameter future_tolerance [s]
FUTURE_TOLERANCE = 2.0


def refuse_future(stamp: float, now: float, tolerance: float, what: str, clock: str = "the node clock") -> None:
    """Raises InputRejected("future") for ``what`` stamped further than ``tolerance`` [s] ahead
    of ``clock`` (default the node clock), at ``now`` [s] (0: no /clock received yet, nothing
    to compare): one message stamped far ahead would become the reference that every later,
    real one is refused against."""
    if now > 0.0 and stamp - now > tolerance:
        raise InputRejected("future", f"{what} stamped {stamp - now:.3f} s ahead of {clock} "
                                      f"(parameter future_tolerance: {tolerance:g} s)")


def future_tolerance_param(what: str):
    """The core Param of a node's ``future_tolerance`` [s] (refuse_future) for the messages ``what``."""
    from ..core.sensors.base import Param
    return Param(FUTURE_TOLERANCE, f"{what} stamped further ahead of the node clock than this [s] is refused "
                                   "(future): one stamped far ahead would become the reference of the next ones",
                 (1.0e-3, 3600.0))


# longest time a stopping node keeps taking already delivered messages [s]
DRAIN_TIMEOUT = 1.5


def wants_help(argv: list[str]) -> bool:
    """``-h`` or ``--help`` among the arguments before ``--ros-args``."""
    user = argv[:argv.index("--ros-args")] if "--ros-args" in argv else argv
    return any(a in ("-h", "--help") for a in user)


def spin(node_factory, args=None, usage: str | None = None) -> int:
    """Create the node, spin it until SIGINT/SIGTERM or it asks to stop, shut down cleanly.

    ``-h``/``--help`` (before ``--ros-args``) prints ``usage`` (the node's topics and parameters)
    and returns 0 without starting the node. The node may define ``finished`` (bool attribute)
    to end the spin by itself and ``close()`` for final work (flushing files) that must run on
    every exit path.

    A node run as its own program (``args`` None: the process's command line) ends the process
    right after its explicit shutdown (files closed, DDS participant deleted, output flushed)
    with ``os._exit``: the interpreter's teardown of numpy, scipy and the ROS libraries is CPU
    work of a few tenths of a second that, on a loaded host, took longer than launch's 5 s grace
    after SIGINT; and the ROS libraries' teardown is bounded by TEARDOWN_BUDGET
    (test/test_stop.py; docs/decisions.md).
    """
    if wants_help(list(sys.argv[1:] if args is None else args)):
        print((usage or "no usage given").strip())
        return 0
    rclpy.init(args=args, signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    stop = {"flag": False}

    def _on_signal(signum, frame):
        stop["flag"] = True

    signal.signal(signal.SIGINT, _on_signal)
    signal.signal(signal.SIGTERM, _on_signal)
    node = executor = None
    code = 0
    try:
        node = node_factory()
        executor = EventsExecutor()  # about 2x the throughput of SingleThreadedExecutor
        executor.add_node(node)
        while not stop["flag"] and not getattr(node, "finished", False) and rclpy.ok():
            executor.spin_once(timeout_sec=0.05)
        # take what is already delivered before closing (a recorder loses nothing): spin until
        # the node's ``activity`` counter stops moving for 0.3 s, at most DRAIN_TIMEOUT s (under
        # a launch a stop escalates to SIGKILL after a few seconds while outside nodes publish)
        deadline, quiet_since, last = time.monotonic() + DRAIN_TIMEOUT, time.monotonic(), None
        while rclpy.ok() and time.monotonic() < deadline and time.monotonic() - quiet_since < 0.3:
            executor.spin_once(timeout_sec=0.02)
            now_activity = getattr(node, "activity", None)
            if now_activity != last:
                last, quiet_since = now_activity, time.monotonic()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except CONFIG_ERRORS as exc:
        print(f"[fatal] {type(exc).__name__}: {exc}", flush=True)   # the user's input: one line
        code = 2
    except Exception as exc:  # noqa: BLE001 - report and exit non-zero, never a traceback storm
        import traceback
        traceback.print_exc()
        print(f"[fatal] {exc}", flush=True)
        code = 1
    finally:
        if node is not None and hasattr(node, "close"):
            node.close()
        if args is None:
            _flush_output()
            exit_guard.arm(TEARDOWN_BUDGET, code)
        if node is not None:
            if executor is not None:
                executor.shutdown()
            node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
        # the node's callbacks hold it in reference cycles, and through it the DDS participant:
        # collected now, the participant leaves (peers drop it at once, its shared-memory files
        # are removed) before the process ends
        executor = node = None
        gc.collect()
        rclpy.get_default_context().destroy()
    if args is None:
        _leave_process(code)
    return code


# longest time the ROS libraries' teardown may take once the node has closed [s]; beyond it the
# process ends without it (nodes/exit_guard.py)
TEARDOWN_BUDGET = 2.0


def _leave_process(code: int) -> None:
    """End the process with ``code`` once everything is flushed, without the interpreter's
    teardown (spin)."""
    logging.shutdown()
    _flush_output()
    os._exit(code)


def _flush_output() -> None:
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):   # a closed or broken pipe: nothing left to save
            pass
