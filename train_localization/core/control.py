"""Speed control through the localisation: a PID on the fused speed (seed 003 section 4.3).

Seed 003 controls the LIMs of its disc with a PID controller on the speed signal of its
loop receiver (Fig. 7, 8). Here the controller takes the fused state (``localization/state``,
the Estimate of core/fusion) and commands the LIMs' thrust [N]: the first consumer that closes
the loop through the localisation.

``SpeedController`` is the functional core of nodes/speed_controller.py: set-points in time
(steps), a PID with the derivative taken as the fused acceleration (no kick at a set-point step,
no differentiation of noise), conditional integration as anti-windup while the thrust is at its
limit, and a stop rule (set-point 0 and the disc below ``stop_speed``: no thrust, integral
cleared; the bearings' static friction holds it). A state without a usable speed (NaN, or a
1-sigma above ``max_speed_stddev``) commands no thrust. The ATP supervision overrides it
(``set_brake``, AtpCommand.BRAKE_*, core/etcs/supervision.py): while a service or emergency
brake is commanded, whatever the state's quality, the thrust is 0, the friction brake demand
``brake_demand`` is full (1; core/dynamics.py ``set_brake``: dissipative, it stops the vehicle
and holds it, never reverses it) and the integral is cleared; once released the PID resumes
from its set-point.

``step_response`` gives the overshoot and the settling time of each set-point step; the
closed loop through the localisation runs offline in core/offline/control_loop.py.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .etcs.supervision import Brake
from .sensors.base import Param, check_declared, resolve_params

CONTROL_PARAMS = {
    "kp": Param(86.0, "proportional gain [N/(m/s)] (2 zeta omega m: omega 2.5 rad/s, zeta 0.9, equivalent mass "
                      "19 kg of the rig, core/dynamics.py)", (0.0, 1.0e6)),
    "ki": Param(119.0, "integral gain [N/m] (omega^2 m)", (0.0, 1.0e6)),
    "kd": Param(2.0, "derivative gain on the fused acceleration [N/(m/s^2)]", (0.0, 1.0e6)),
    "force_limit": Param(0.0, "largest thrust command [N]; 0 = the LIMs' limit (core/dynamics.py)", (0.0, 1.0e6)),
    "stop_speed": Param(0.3, "with set-point 0, below this fused speed the controller lets go [m/s]",
                        (0.0, 10.0)),
    "max_speed_stddev": Param(1.0, "fused speed 1-sigma above which the state is not used [m/s]", (0.01, 100.0)),
    "settling_band": Param(0.02, "settling band, fraction of the step [1] (the 2 % criterion)", (1.0e-4, 0.5)),
}
check_declared(CONTROL_PARAMS, "CONTROL_PARAMS")


@dataclass(frozen=True)
class SetPoint:
    t: float        # from this time [s]
    speed: float    # [m/s]


def parse_setpoints(entries) -> tuple[SetPoint, ...]:
    """Set-points of a scenario's ``control: {setpoints: [{t, speed}, ...]}`` (also
    ``speed_kmh``), sorted by time; ValueError in one line for a malformed list."""
    out = []
    for e in entries or []:
        if not isinstance(e, dict) or "t" not in e or not ("speed" in e or "speed_kmh" in e):
            raise ValueError(f"control set-point {e!r} needs 't' [s] and 'speed' [m/s] or 'speed_kmh'")
        speed = float(e["speed"]) if "speed" in e else float(e["speed_kmh"]) / 3.6
        if not (math.isfinite(speed) and math.isfinite(float(e["t"]))):
            raise ValueError(f"control set-point {e!r} is not finite")
        out.append(SetPoint(float(e["t"]), speed))
    if not out:
        raise ValueError("control needs at least one set-point")
    return tuple(sorted(out, key=lambda s: s.t))


def control_config(control: dict) -> tuple[dict, tuple[SetPoint, ...]]:
    """(resolved controller parameters, set-points) of a scenario's ``control`` section."""
    control = dict(control or {})
    kind = control.pop("kind", "pid")
    if kind != "pid":
        raise ValueError(f"control kind {kind!r} unknown; known: pid")
    setpoints = parse_setpoints(control.pop("setpoints", None))
    return resolve_params(CONTROL_PARAMS, control), setpoints


class SpeedController:
    """PID speed controller on the fused state; ``update`` returns the thrust command [N],
    no thrust and the friction brake's full demand while ``set_brake`` holds a brake (module doc)."""

    def __init__(self, params: dict, setpoints: tuple[SetPoint, ...], force_limit: float):
        self.params = params
        self.setpoints = setpoints
        self.force_limit = params["force_limit"] or force_limit
        self.integral = 0.0      # [m]
        self.t_last: float | None = None
        self.command = 0.0
        self.brake = Brake.NONE  # commanded by the ATP supervision
        self.brake_demand = 0.0  # friction brake demand 0..1 (core/dynamics.py set_brake)

    def set_brake(self, brake: int) -> None:
        """The ATP's brake command (Brake / AtpCommand.BRAKE_*: 0 none, 1 service, 2 emergency;
        ValueError for another value): the friction brake demand at once, the thrust from the next
        ``update``."""
        self.brake = Brake(int(brake))
        self.brake_demand = 0.0 if self.brake == Brake.NONE else 1.0

    def setpoint(self, t: float) -> float:
        """Set-point speed at ``t`` [m/s] (the last one that has started; 0 before the first)."""
        v = 0.0
        for sp in self.setpoints:
            if sp.t <= t:
                v = sp.speed
        return v

    def update(self, t: float, speed: float, acceleration: float = 0.0, speed_stddev: float = 0.0) -> float:
        """Thrust command [N] for the fused ``speed`` [m/s], ``acceleration`` [m/s^2] at ``t`` [s]."""
        p = self.params
        dt = 0.0 if self.t_last is None or t <= self.t_last else t - self.t_last
        self.t_last = t
        target = self.setpoint(t)
        if self.brake != Brake.NONE:   # ATP intervention: no thrust, the friction brake (set_brake), no integral
            self.integral, self.command = 0.0, 0.0
            return 0.0
        if not (math.isfinite(speed) and math.isfinite(speed_stddev)) or speed_stddev > p["max_speed_stddev"]:
            self.integral, self.command = 0.0, 0.0
            return 0.0
        if target == 0.0 and abs(speed) < p["stop_speed"]:
            self.integral, self.command = 0.0, 0.0
            return 0.0
        err = target - speed
        d_term = -p["kd"] * acceleration if math.isfinite(acceleration) else 0.0
        u = p["kp"] * err + p["ki"] * self.integral + d_term
        limit = self.force_limit
        saturated = abs(u) >= limit and math.copysign(1.0, u) == math.copysign(1.0, err)
        if not saturated:   # conditional integration: no wind-up while the thrust is at its limit
            self.integral += err * dt
            u = p["kp"] * err + p["ki"] * self.integral + d_term
        self.command = max(-limit, min(limit, u))
        return self.command


# --------------------------------------------------------------------------- figures
@dataclass
class StepFigures:
    t: float                   # time of the step [s]
    v_from: float              # [m/s]
    v_to: float                # [m/s]
    overshoot: float           # [%] of the step
    settling_time: float | None  # [s] after the step into the band for good; None: not settled
    peak_error: float          # largest |v - v_to| once first in the band [m/s]


def step_response(t: np.ndarray, speed: np.ndarray, setpoints: tuple[SetPoint, ...], band: float = 0.02,
                  t_end: float | None = None) -> list[StepFigures]:
    """Overshoot [%] and settling time [s] (``band`` x the step) of every set-point step.

    Each step is judged until the next set-point (or ``t_end``); overshoot is the largest
    excursion beyond the new set-point in the direction of the step, over the step size."""
    t, speed = np.asarray(t, float), np.asarray(speed, float)
    t_end = float(t[-1]) if t_end is None else t_end
    out = []
    prev = 0.0
    for i, sp in enumerate(setpoints):
        t1 = setpoints[i + 1].t if i + 1 < len(setpoints) else t_end
        step = sp.speed - prev
        if step == 0.0:
            continue
        sel = (t >= sp.t) & (t <= t1)
        if not sel.any():
            break
        tt, vv = t[sel], speed[sel]
        direction = math.copysign(1.0, step)
        over = max(0.0, float(np.max((vv - sp.speed) * direction))) / abs(step) * 100.0
        outside = np.abs(vv - sp.speed) > band * abs(step)
        if outside[-1]:
            settle = None
        else:
            last_out = np.flatnonzero(outside)
            settle = float(tt[last_out[-1] + 1] - sp.t) if last_out.size else 0.0
        inside = np.flatnonzero(~outside)
        peak = float(np.max(np.abs(vv[inside[0]:] - sp.speed))) if inside.size else math.inf
        out.append(StepFigures(sp.t, prev, sp.speed, over, settle, peak))
        prev = sp.speed
    return out
