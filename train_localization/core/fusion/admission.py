"""Admission: every check that protects the filter from its inputs, in one place.

``FusionRunner.add`` runs it for every path (the live node, ``tl_replay``, the campaign,
the benchmarks and the tests); what is refused is counted by reason and never reaches
the filter. The node keeps only what is about DDS (a message on another sensor's topic).

========================  ====================================================================
reason                    refused
========================  ====================================================================
``nan``                   a stamp, value or stddev that is NaN or infinite
``stddev``                a stddev or duration <= 0
``implausible``           beyond the physical limits (core/measurements.py)
``too_long``              an id (sensor, unit, track, reference) beyond 64 characters
``unknown_sensor``        a sensor class the fusion is not configured for
``not_fused``             a measurement of a kind the filter does not use (a section's occupancy)
``wrong_kind``            a measurement of another kind than its sensor gives
``wrong_track``           a fix that names another track than the fusion's
``off_track``             a fix beyond the track's ends by more than 100 m + 5 sigma
``below_model``           a stddev below its sensor's error model (ErrorModel.min_stddev):
                          a message never claims more than its sensor's model allows
``unknown_reference``     a fix whose reference id is not in the track's equipment
``reference_mismatch``    a fix that lies elsewhere than the reference it names
``future``                stamped further ahead of the runner's clock than ``history``
``duplicate``             (the filter's history) a measurement already taken
``overlap``               (the filter's history) a distance increment whose span (stamp -
                          duration .. stamp) overlaps one taken from the same sensor and unit:
                          an echo or a repetition, whose distance would count twice
``too_late``              (the filter's history) older than ``history`` or the last reset
========================  ====================================================================
"""
from __future__ import annotations

import math

from ..measurements import (MAX_CHAINAGE, MAX_SPEED, STDDEV_RANGE, Acceleration, DistanceIncrement, PositionFix,
                            SpeedMeasurement, YawRate)
from ..signals import InputRejected
from .config import FusionConfig

# the measurement type of each kind of sensor (ErrorModel.measures)
KIND_OF = {"position": PositionFix, "speed": SpeedMeasurement, "distance": DistanceIncrement, "yaw_rate": YawRate,
           "acceleration": Acceleration}

# a fix this far beyond the track's ends [m] (plus 5 of its sigma) cannot be of a train on it
OFF_TRACK_MARGIN = 100.0


class Admission:
    """Checks a measurement against the physical limits, the configured sensors' error
    models and the track; ``check`` raises InputRejected with the reason."""

    def __init__(self, config: FusionConfig):
        self.cfg = config
        self.models = config.models
        self.track_length = config.track.length if config.track is not None else math.inf

    def check(self, m, clock: float | None) -> None:
        """Raises InputRejected if ``m`` may not reach the filter. ``clock``: the runner's
        time [s] (the node clock, or the last output time offline), None before it has one."""
        m.validate()
        model = self.models.get(m.sensor)
        if model is None:
            raise InputRejected("unknown_sensor", f"measurement of sensor {m.sensor[:64]!r}, which the fusion "
                                f"is not configured for (configured: {', '.join(sorted(self.models))})")
        kind = KIND_OF.get(model.measures)
        if kind is None:
            raise InputRejected("not_fused", f"measurement of sensor {m.sensor!r}, which measures "
                                f"{model.measures}: the fusion does not use that kind")
        if not isinstance(m, kind):
            raise InputRejected("wrong_kind", f"{type(m).__name__} of sensor {m.sensor!r}, which "
                                f"measures {model.measures} ({kind.__name__})")
        if clock is not None and m.stamp - clock > self.cfg.history:
            raise InputRejected("future", f"stamp {m.stamp - clock:.3f} s ahead of the fusion's clock "
                                f"(history {self.cfg.history:g} s)")
        if isinstance(m, PositionFix):
            if m.track_id and self.cfg.track_id and m.track_id != self.cfg.track_id:
                raise InputRejected("wrong_track", f"fix on track {m.track_id[:64]!r}, not {self.cfg.track_id!r}")
            self._on_track(m.position, m.position_stddev, "fix")
        refusal = model.refusal(m)
        if refusal is not None:
            raise refusal

    def check_set_position(self, position: float, position_stddev: float, speed: float, speed_stddev: float) -> None:
        """Raises InputRejected (one line) for an operator's position [m] and speed [m/s] with
        their 1-sigmas that the filter cannot take: not finite, a stddev outside the physical
        range, a speed beyond any train, a position off the track."""
        values = {"position": position, "position_stddev": position_stddev, "speed": speed,
                  "speed_stddev": speed_stddev}
        for name, value in values.items():
            if not math.isfinite(value):
                raise InputRejected("nan", f"{name} is {value!r}")
        for name in ("position_stddev", "speed_stddev"):
            if not STDDEV_RANGE[0] <= values[name] <= STDDEV_RANGE[1]:
                raise InputRejected("implausible", f"{name} {values[name]:g} outside {STDDEV_RANGE[0]:g} .. "
                                                   f"{STDDEV_RANGE[1]:g}")
        if abs(speed) > MAX_SPEED:
            raise InputRejected("implausible", f"speed {speed:g} m/s beyond {MAX_SPEED:g} m/s")
        self._on_track(position, position_stddev, "position")

    def _on_track(self, position: float, stddev: float, what: str) -> None:
        """Raises ``off_track`` for a ``position`` [m] beyond the track's ends (no line is longer
        than MAX_CHAINAGE) by more than OFF_TRACK_MARGIN + 5 ``stddev`` [m]."""
        margin = OFF_TRACK_MARGIN + 5.0 * stddev
        if not -margin <= position <= min(self.track_length, MAX_CHAINAGE) + margin:
            raise InputRejected("off_track", f"{what} at {position:.3f} m, off the track "
                                             f"(0 .. {self.track_length:.3f} m)")
