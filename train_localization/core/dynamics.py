"""Longitudinal dynamics driven by a traction command: the rotating disc of seed 003.

The rig (seed 003 section 3.1): two LIMs of at most 30 N each, placed symmetrically about the
axis, drive an aluminium disc of 120 cm diameter (their reaction plate) that carries the loop.
Everything is expressed along the loop (chainage, core/sensors/rig_loop.py): the disc's moment
of inertia J becomes the equivalent mass m = J / r_loop^2 and the LIM thrust, acting at
``lim_radius``, the force F r_lim / r_loop.

    m dv/dt = F - sign(v) (a + b |v| + c v^2)      (Davis form of the running resistance)

F follows the command with a first-order lag ``force_lag`` and is limited to the LIMs'
combined thrust (the LIMs drive and brake: a LIM reverses its travelling field). At a
standstill the constant term a is static friction: the disc stays at rest while |F| <= a.

A friction brake (``set_brake``: a demand 0..1 of ``brake_force``, following it with the same
lag) is dissipative: a force B against the motion that brings the vehicle to rest and holds
it there (with the static friction: at rest while |F| <= a + B), never reversing it. The ATP
supervision's brake acts through it (core/control.py, core/etcs/supervision.py).
The position is integrated as an unwrapped distance; ``state`` gives the chainage wrapped
round a closed track.

The seed gives the LIM force only; the inertia, the lever and the resistance coefficients are
assumptions (``DYNAMICS_PARAMS``).
"""
from __future__ import annotations

import math

from .truth import TruthState
from .sensors.base import Param, check_declared, resolve_params
from .track import Track

DYNAMICS_PARAMS = {
    "lim_force": Param(30.0, "largest thrust of one LIM [N] (seed 003 section 3.1: 30 N)", (0.0, 1.0e6)),
    "lims": Param(2, "LIMs driving in parallel [1] (seed 003 section 3.1: two, single or parallel operation)",
                  (1, 16)),
    "lim_radius": Param(0.55, "radius at which the LIMs act on the disc [m] (assumption: near the 0.6 m rim of "
                              "the 120 cm reaction plate)", (0.01, 100.0)),
    "inertia": Param(4.8, "moment of inertia of the disc and the loop ring [kg m^2] (assumption: 6 mm "
                          "aluminium, 120 cm: 3.3 kg m^2; wooden ring 15 mm thick, radii 0.4-0.6 m: 1.5 kg m^2)",
                     (1.0e-3, 1.0e6)),
    "force_lag": Param(0.05, "time constant of the thrust following its command [s] (assumption: LIM current "
                             "control)", (0.0, 10.0)),
    "resistance_a": Param(1.5, "running resistance, constant term at the loop radius [N] (assumption: bearing "
                               "friction; static friction at a standstill)", (0.0, 1.0e5)),
    "resistance_b": Param(0.05, "running resistance, linear term [N s/m] (assumption: bearings, eddy drag)",
                          (0.0, 1.0e5)),
    "resistance_c": Param(0.0065, "running resistance, quadratic term [N s^2/m^2] (assumption: windage of a "
                                  "1.2 m disc, both faces, turbulent moment coefficient 0.146 Re^-0.2, about "
                                  "5 N at 100 km/h)", (0.0, 1.0e3)),
    "brake_force": Param(0.0, "force of the friction brake at full demand [N]; 0 = the drive's thrust limit "
                              "(lim_force x lims at the loop)", (0.0, 1.0e7)),
    "substep": Param(0.001, "integration step [s]", (1.0e-5, 0.1)),
}
check_declared(DYNAMICS_PARAMS, "DYNAMICS_PARAMS")


class Dynamics:
    """Integrates force -> speed -> position of a disc (or any vehicle) along its track."""

    def __init__(self, params: dict | None, track: Track, position: float = 0.0, speed: float = 0.0):
        self.params = resolve_params(DYNAMICS_PARAMS, params)
        p = self.params
        self.track = track
        # radius of the loop: a closed track is the loop's circle
        self.loop_radius = track.length / (2.0 * math.pi) if track.closed else p["lim_radius"]
        lever = p["lim_radius"] / self.loop_radius
        self.mass = p["inertia"] / self.loop_radius ** 2           # equivalent mass at the loop [kg]
        self.force_limit = p["lim_force"] * p["lims"] * lever       # largest thrust at the loop [N]
        self.distance = float(position)   # unwrapped [m]
        self.speed = float(speed)
        self.acceleration = 0.0
        self.force = 0.0                  # thrust acting [N]
        self.command = 0.0                # thrust commanded [N]
        self.brake_limit = p["brake_force"] or self.force_limit   # friction brake at full demand [N]
        self.brake = 0.0                  # friction brake acting [N], >= 0
        self.brake_command = 0.0          # friction brake commanded [N]
        self.t = 0.0

    def resistance(self, speed: float) -> float:
        """Running resistance at ``speed`` [N] (positive, opposing the motion)."""
        p = self.params
        v = abs(speed)
        return p["resistance_a"] + p["resistance_b"] * v + p["resistance_c"] * v * v

    def max_acceleration(self, speed: float = 0.0) -> float:
        """Largest acceleration in the direction of motion at ``speed`` [m/s^2]: full thrust less the resistance."""
        return (self.force_limit - self.resistance(speed)) / self.mass

    def set_command(self, force: float) -> None:
        """Thrust command [N] along the track, limited to what the LIMs give."""
        self.command = max(-self.force_limit, min(self.force_limit, float(force))) if math.isfinite(force) else 0.0

    def set_brake(self, demand: float) -> None:
        """Friction brake demand in [0, 1] (clipped; NaN: full, the safe side) of ``brake_force``."""
        demand = 1.0 if not math.isfinite(demand) else max(0.0, min(1.0, float(demand)))
        self.brake_command = demand * self.brake_limit

    def step(self, dt: float) -> TruthState:
        """Advance by ``dt`` [s]; returns the new state (chainage wrapped on a closed track)."""
        p = self.params
        n = max(1, int(math.ceil(dt / p["substep"] - 1e-9)))
        h = dt / n
        lag = p["force_lag"]
        k = 1.0 - math.exp(-h / lag) if lag > 0 else 1.0
        for _ in range(n):
            self.force += k * (self.command - self.force)
            self.brake += k * (self.brake_command - self.brake)
            v = self.speed
            hold = p["resistance_a"] + self.brake           # static friction and the brake
            if v == 0.0 and abs(self.force) <= hold:
                acc = 0.0                                   # held at rest
            else:
                direction = math.copysign(1.0, v) if v != 0.0 else math.copysign(1.0, self.force)
                acc = (self.force - direction * (self.resistance(v) + self.brake)) / self.mass
            v_new = v + acc * h
            if v != 0.0 and v_new * v < 0.0 and abs(self.force) <= hold:
                v_new = 0.0                                 # comes to rest: friction and brakes do not reverse it
                acc = -v / h
            self.distance += 0.5 * (v + v_new) * h
            self.speed, self.acceleration = v_new, acc
        self.t += dt
        return self.state()

    def state(self, stamp: float | None = None) -> TruthState:
        return TruthState(self.t if stamp is None else stamp, float(self.track.wrap(self.distance)), self.speed,
                          self.acceleration)
