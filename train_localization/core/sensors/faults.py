"""The fault modes a sensor's error model can name (ErrorModel.faults), in one place.

Each sensor declares which of these it has (its ``error_model``); the fusion builds its
checks and hypotheses from the declared modes by their effect, never from sensor names.
"""
from __future__ import annotations

from typing import NamedTuple


class FaultMode(NamedTuple):
    """One way a sensor can be wrong beyond its white noise and its modelled slow errors."""

    name: str
    effect: str          # "outlier": a confident wrong fix; "speed": a relative sensor reads a wrong
                         # speed for a while; "offset": a run of fixes shares one error; "silence": no
                         # data (the sensor's timeout covers it)
    persistent: bool     # lasts until repaired: no test of the sensor's own readings tells it from motion
    description: str


CATALOGUE = (
    FaultMode("slip", "speed", False, "a driven wheel turns faster than the train under traction "
                                      "(poor adhesion, seed 002); bounded in ratio and duration"),
    FaultMode("slide", "speed", False, "a braked wheel turns slower than the train under braking"),
    FaultMode("scale_fault", "speed", True, "a speed sensor's scale off by up to its scale_fault_sigma "
                                            "(a Doppler radar's beam over water, snow or a misaligned mount)"),
    FaultMode("wear", "speed", True, "a wheel's diameter beyond its tolerance by up to its scale_fault_sigma "
                                     "(a missed re-calibration, a re-profiled or changed wheel whose "
                                     "diameter was not re-entered)"),
    FaultMode("bias_step", "speed", True, "an accelerometer's bias steps by up to its fault_bias_sigma (a mount "
                                          "worked loose and tilted: g sin(tilt), 0.017 m/s^2 per 0.1 deg; a "
                                          "shock to the proof mass): the speed integrated from it drifts off "
                                          "linearly, which only another speed source or the fixes show"),
    FaultMode("offset", "offset", True, "a run of a position sensor's fixes shares one offset, each within the "
                                        "single-fix gate of its own 1-sigma, so that every check of one fix "
                                        "passes (a balise laid or surveyed off, a wrong antenna offset or "
                                        "latency, a reversal over the same installation errors, a run of "
                                        "forged fixes)"),
    FaultMode("dropout", "silence", False, "the sensor is silent for a while"),
    FaultMode("outage", "silence", False, "a wayside device or base station is out"),
    FaultMode("nlos", "outlier", False, "a range or fix from a reflected path (mm-wave, DGPS multipath)"),
    FaultMode("misread", "outlier", False, "a reference read as another one (a balise, a lug, a tag)"),
    FaultMode("miscount", "outlier", False, "a counted reference (an axle, a period, a crossing) gained or lost"),
)
FAULT_MODES = tuple(mode.name for mode in CATALOGUE)

# fault modes by which an absolute sensor can report a confident wrong fix
OUTLIER = frozenset(mode.name for mode in CATALOGUE if mode.effect == "outlier")
# fault modes that make a relative sensor read a wrong speed for a while (its error states can
# absorb them before a test fires)
SPEED = frozenset(mode.name for mode in CATALOGUE if mode.effect == "speed")
# the wheel's adhesion faults: transient, bounded, under drive only
ADHESION = frozenset(("slip", "slide"))
# speed faults that persist: nothing but a fix or another speed source can show them
PERSISTENT = frozenset(mode.name for mode in CATALOGUE if mode.effect == "speed" and mode.persistent)
# a fix sensor's offset of a run of fixes (the sensors whose model calls their fixes independent,
# one per reference: a fix-bias state models the others' persistent errors)
OFFSET = frozenset(mode.name for mode in CATALOGUE if mode.effect == "offset")
# persistent faults that are a constant scale error beyond the sensor's tolerance (a missed
# calibration): the sensor's own dead reckoning, its scale opened by the fault's size and learnt
# from the fixes, is a solution valid under them
CALIBRATION = frozenset(("wear",))
