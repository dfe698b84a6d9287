"""AF jointless track circuits UM71C and TI21 (wayside train detection), seed 004.

Principle (seed 004 section 2.1, Fig. 1): the two rails are part of an electric circuit
from a transmitter to a receiver; the axles of a train short the rails, the receiver
level falls and the circuit reports the section occupied.

Systems (seed 004 section 3):
  * UM71C (high-speed line, section 3.1, Table 1): jointless, about 1,500 m per circuit;
    carriers 2040 / 2760 Hz on track T1 (down line) and 2400 / 3120 Hz on track T2 (up
    line), used alternately along a track (Fig. 3) so that neighbouring circuits and the
    other track differ; each carrier is FM-modulated by the 25.68 Hz detection signal,
    which the receiver demodulates (the 27-bit ATC code it also carries is not evaluated
    by the receiver and not modelled). The transmitter and the receiver sit at opposite
    ends (section 4.2); compensating capacitors are laid across the rails every 60 m at
    2040 / 2400 Hz and every 80 m at 2760 / 3120 Hz (section 4.2).
  * TI21 (conventional line, section 3.2, Table 2): 8 frequencies A-H between 1,532 and
    2,610 Hz in the pairs A/B, C/D, E/F, G/H, each nominal +-17 Hz (FSK); one pair per
    track, its two frequencies alternating along it (A, B, A, ...); neighbouring circuits
    are separated electrically by two tuned units over 20 m of track (Fig. 4). The seed
    gives no compensating capacitors for TI21 and no circuit length; none are laid here.

Transmission line (a chain of ABCD matrices at the carrier frequency): the rail pair has
the series impedance z = R'(f) + j omega L' per metre and the ballast the shunt
conductance G' = 1 / (ballast resistance x 1000 m) per metre; a uniform piece of length d
is [[cosh gd, Z0 sinh gd], [sinh gd / Z0, cosh gd]] with g = sqrt(z G'), Z0 = sqrt(z / G').
Constants (none is in seed 004; each is an assumption of the usual order, a parameter):
  * L' = 1.5 uH/m loop inductance of the rail pair (1.3-1.6 uH/m for UIC 60 track);
  * R' = 1.2 mOhm/m loop resistance at 2 kHz, scaled with sqrt(f) (skin effect: rail steel
    sigma ~ 4.5 MS/m, mu_r ~ 100 -> skin depth 0.53 mm at 2 kHz; rail perimeter ~ 0.7 m ->
    0.6 mOhm/m per rail);
  * ballast resistance 2-20 Ohm km (wet .. dry); the receiver is adjusted at the lowest one
    (``adjust_ballast``): its clear level is 1 there and rises in dry weather;
  * compensating capacitors 25 uF (lumped shunts, lossless; 22-33 uF is the usual size);
  * transmitter: a source behind 1 Ohm, receiver input 5 Ohm (resistive);
  * an axle: a shunt resistance across the rails at its chainage (``shunt_resistance``,
    0.06 Ohm, the usual test shunt; a rusty rail or a light vehicle shunts with 0.5 Ohm
    and far more).
The tuned zone (electrical joint) of length ``zone`` around each boundary belongs to both
circuits: a circuit's line runs from its transmitter at start - zone/2 to its receiver at
end + zone/2 (the tuning unit beyond each terminal isolates the neighbour at this carrier;
modelled as an ideal isolation), so an axle in the zone shunts both circuits, the overlap
of seed 004 section 3.1 that keeps the detection continuous. Zone length: 20 m for TI21
(seed 004 section 3.2); 24 m for UM71C (assumption: the seed gives none; UM71 electrical
joints are 20-26 m).

Receiver level (raw signal): |V_rx| / |V_rx, clear at adjust_ballast| x the receiver's
adjustment gain (``adjust_sigma``), the neighbour's carrier that passes its band filter
(``crosstalk``, power sum) and Gaussian noise on both quadratures of the demodulated
carrier (``noise_sigma``). It depends only on which axles are in the circuit and where:
a circuit without axles keeps its clear level (cached); for one with axles the chain is
multiplied cell by cell between the capacitors, the empty cells from a cache.
Critical shunt (the worst position in the circuit, threshold 0.5): about 0.2-0.3 Ohm with
dry ballast (20 Ohm km) and 0.6-0.9 Ohm with wet (2 Ohm km) for both systems at their
nominal lengths (test_sensor_track_circuit).

Track equipment (kind ``track_circuit``)::

    track_circuit:
      - {id: TC01, start: 0.0, end: 1500.0, system: UM71C, line: T1}       # carrier allocated
      - {id: TC02, start: 1500.0, end: 3000.0, system: UM71C, carrier: 2760}
      - {id: TI01, start: 0.0, end: 800.0, system: TI21, pair: A/B}        # A, then B, ...
      - {every: 1500.0, start: 0.0, end: 4500.0, id: "TC{n:02d}", length: 1500.0,
         system: UM71C, line: T1}                      # four circuits 0 .. 6000 m

``start``/``end`` (or ``position``/``length``) are the boundaries (tuned-zone centres) [m];
``system`` UM71C (default) or TI21; ``line`` T1 (default) or T2 for UM71C, ``pair`` A/B
(default), C/D, E/F or G/H for TI21; ``carrier`` (Hz, or a letter A-H for TI21) fixes a
circuit's carrier, else the circuits of one system and line/pair are given the two
carriers alternately in chainage order (seed 004 Fig. 3, section 3.2); ``zone`` [m]
overrides the tuned-zone length. Circuits must not overlap; touching circuits (end ==
next start) are neighbours and must differ in carrier. Parameter ``circuits`` restricts a
device to a subset.

Raw signal: one channel ``<id>.level`` [1] per circuit at ``sample_rate`` (100 Hz: the
demodulated level is a slow signal; the receiver's own delay filters noise, section 3.1).

Faults (``faults``, ';'-separated, times in s): ``ID@T0[-T1]:poor_shunt`` (from T0, until
T1 if given: every axle on the rails of circuit ID, zones included, shunts with
``poor_shunt_resistance``: the train is not seen, the dangerous side); ``ID@T:broken_rail``
(a rail of ID breaks at its middle: ``break_resistance`` in series, the circuit drops
with no train, the safe side); ``ID@T:tx_failed`` (ID's transmitter stops: OCCUPIED with
no train, safe side); ``ID@T0[-T1]:interference`` (a failed tuning unit lets the carrier of
the neighbour whose transmitter sits at ID's receiver end into ID's receiver,
``interference_coupling`` of its voltage: it can hold the level up under a train, the
dangerous side).

Decoder: per circuit a hysteresis (low below ``threshold_drop``, high again above
``threshold_pick``); OCCUPIED when low for ``drop_delay``, CLEAR when high for
``pickup_delay`` (the stamp of a change is the time it is decided). Outputs:
  * SectionOccupancy (source = unit id, default "track_circuit") of every circuit at the
    first block, on every change and every ``report_period``; axle counts are 0 (a track
    circuit counts no axles);
  * train lost: when a circuit clears and no neighbour is low or occupied, the train has
    vanished (a poor shunt, a masked receiver): the neighbour ahead (direction of the last
    hand-over; both neighbours while none was seen) becomes DISTURBED, latched until
    ``reset_section`` (``stats["train_lost"]``). A circuit at the end of the monitored
    circuits (or before a gap) has no neighbour there: a train leaving the area is no loss;
  * boundary fix: when a CLEAR circuit drops while its neighbour on one side is OCCUPIED
    (a hand-over), a PositionFix of the train front where the entering axle shunted the
    new circuit down: the new circuit's line begins at the tuned unit on the near edge of
    the zone, half a zone before the boundary in the running direction d, so the front is
    at boundary - d x zone/2 + o x ``first_axle_offset`` (the train leads), or + o x
    ``last_axle_offset`` (the train backs; skipped if 0), stamped at the onset of the drop
    (the first sample below the threshold, not the decision after the delay). Its stddev:
    half the zone as a persistent part (a poorer shunt or wetter ballast moves the drop
    into the zone, the same way for every hand-over: the error model's fix bias, so that
    consecutive fixes do not average it away), a quarter zone white, the axle offset and
    the timing (``max_speed`` x a sample / sqrt 12): 1-sigma 13.4 m for UM71C, 11.2 m
    for TI21. No fix when the drop has no occupied
    neighbour (a train appearing, a broken rail), when the neighbour is DISTURBED, or when
    the train that entered the neighbour by a hand-over cannot have crossed it yet at
    ``max_speed`` (a broken rail or failed transmitter ahead of the train:
    ``stats["fix_withheld"]``). A circuit failing ahead of a train that started in the
    neighbour (no hand-over seen) still gives a wrong fix, up to a circuit length off:
    hence the error model's fault mode "miscount", which the fusion checks fixes for.

Not modelled: the ATC code (27 bits, 0.88-17.52 Hz, seed 004 section 3.1) and the FSK of
TI21 (the carrier's nominal frequency is used; +-17 Hz changes the line by ~1 %); the
detailed tuned-zone circuit (its resonant units); rail-to-earth and traction return
currents; several trains (one simulated train, like the axle counter).
"""
from __future__ import annotations

import math

import numpy as np

from ..measurements import CLEAR, DISTURBED, OCCUPIED, PositionFix, SectionOccupancy, SectionState
from ..signals import InputRejected, RawBlock
from ..track import Track, TrackError, extent
from .base import Decoder, ErrorModel, Param, ReferenceTable, ReferenceWindow, SensorSpec, Simulator

KIND = "track_circuit"
SENSOR = "track_circuit"

# seed 004 section 3.1 and Table 1: UM71C carriers [Hz] by track, (F1, F2) used alternately
UM71C_CARRIERS = {"T1": (2040.0, 2760.0), "T2": (2400.0, 3120.0)}
UM71C_LENGTH = 1500.0            # [m] nominal circuit length (seed 004 section 3.1)
# seed 004 section 4.2: compensating capacitors every 60 m at 2040/2400 Hz, 80 m at 2760/3120 Hz
CAPACITOR_SPACING = {2040.0: 60.0, 2400.0: 60.0, 2760.0: 80.0, 3120.0: 80.0}
# seed 004 Table 2: TI21 frequency type -> (nominal, low, high) [Hz]; pairs by track
TI21_FREQUENCIES = {
    "A": (1699.0, 1682.0, 1716.0), "B": (2296.0, 2279.0, 2313.0),
    "C": (1996.0, 1979.0, 2013.0), "D": (2593.0, 2576.0, 2610.0),
    "E": (1549.0, 1532.0, 1566.0), "F": (2146.0, 2129.0, 2163.0),
    "G": (1848.0, 1831.0, 1865.0), "H": (2445.0, 2428.0, 2462.0),
}
TI21_PAIRS = {"A/B": ("A", "B"), "C/D": ("C", "D"), "E/F": ("E", "F"), "G/H": ("G", "H")}
TI21_ZONE = 20.0                 # [m] tuned units over 20 m of track (seed 004 section 3.2)
SYSTEMS = ("UM71C", "TI21")

PARAMS = {
    "rail_inductance": Param(1.5e-6, "loop inductance of the rail pair [H/m] (assumption: 1.3-1.6 uH/m for UIC 60 "
                                     "track)", (1.0e-7, 1.0e-5)),
    "rail_resistance": Param(1.2e-3, "loop resistance of the rail pair at 2 kHz [Ohm/m], scaled with sqrt(f) "
                                     "(assumption: skin depth 0.53 mm in rail steel, 0.7 m rail perimeter)",
                             (1.0e-5, 0.1)),
    "ballast_resistance": Param(5.0, "ballast resistance of the simulated track [Ohm km] (assumption: 2 wet .. "
                                     "20 dry)", (0.5, 1000.0)),
    "adjust_ballast": Param(2.0, "ballast resistance at which the receivers are adjusted to level 1 [Ohm km] "
                                 "(the design minimum; assumption)", (0.5, 1000.0)),
    "capacitor": Param(25.0e-6, "UM71C compensating capacitor [F], laid every 60 m (2040/2400 Hz) or 80 m "
                                "(2760/3120 Hz) (spacing: seed 004 section 4.2; value: assumption, 22-33 uF)",
                       (0.0, 1.0e-3)),
    "source_impedance": Param(1.0, "transmitter output resistance at the rails [Ohm] (assumption)", (0.01, 100.0)),
    "receiver_impedance": Param(5.0, "receiver input resistance at the rails [Ohm] (assumption)", (0.01, 1000.0)),
    "zone_um71c": Param(24.0, "tuned-zone (electrical joint) length of UM71C [m] (assumption: 20-26 m; not in "
                              "seed 004)", (1.0, 100.0)),
    "zone_ti21": Param(TI21_ZONE, "tuned-zone length of TI21 [m] (seed 004 section 3.2: two tuned units over 20 m)",
                       (1.0, 100.0)),
    "shunt_resistance": Param(0.06, "shunt resistance of one axle of the simulated train [Ohm] (the usual test "
                                    "shunt; assumption)", (1.0e-4, 1.0e4)),
    "poor_shunt_resistance": Param(20.0, "axle shunt resistance in a 'poor_shunt' fault [Ohm] (rusty rail, light "
                                         "vehicle: 0.5 Ohm and far more; assumption)", (1.0e-4, 1.0e6)),
    "break_resistance": Param(100.0, "series resistance of a broken rail [Ohm] (the current's way round through "
                                     "ballast and structures; assumption)", (0.0, 1.0e6)),
    "interference_coupling": Param(0.3, "fraction of the neighbour's transmitter voltage reaching a receiver in "
                                        "an 'interference' fault [1] (failed tuning unit; assumption)", (0.0, 10.0)),
    "crosstalk": Param(0.01, "fraction of the neighbour's transmitter voltage passing a receiver's band filter "
                             "[1] (-40 dB; assumption: carriers at least 360 Hz apart)", (0.0, 1.0)),
    "adjust_sigma": Param(0.03, "1-sigma error of a receiver's adjusted gain [fraction] (assumption)", (0.0, 0.5)),
    "noise_sigma": Param(0.02, "1-sigma noise of each quadrature of the demodulated level [1] (traction-current "
                               "harmonics, demodulator; assumption)", (0.0, 1.0)),
    "circuits": Param("", "comma-separated circuit ids of this device; empty = all circuits of the track"),
    "orientation": Param(0, "+1: train front faces increasing chainage, -1: decreasing, 0: auto (first motion / "
                            "first hand-over) [1]", (-1, 1)),
    "threshold_drop": Param(0.5, "decoder: receiver level below which the circuit is shunted [1] (fraction of the "
                                 "adjusted clear level; assumption)", (0.0, 10.0)),
    "threshold_pick": Param(0.6, "decoder: level above which it is free again (hysteresis) [1] (assumption)",
                            (0.0, 10.0)),
    "drop_delay": Param(0.2, "decoder: time the level must stay low before OCCUPIED [s] (the receiver's delay "
                             "against noise, seed 004 section 3.1; value: assumption)", (0.0, 60.0)),
    "pickup_delay": Param(1.5, "decoder: time the level must stay high before CLEAR [s] (rides through a "
                               "momentary loss of shunt; assumption)", (0.0, 600.0)),
    "adc_range": Param(4.0, "receiver level output range [1]; a level beyond it (or below -1) is implausible",
                       (0.5, 100.0)),
    "front_first": Param(False, "every train passes front first (wayside receivers on a line with trains of both "
                                "directions): each hand-over's direction is its train's orientation, and "
                                "``orientation`` is not used by the decoder; a backing train's fix would be off by "
                                "its length (left to the association with the trains' fused intervals)"),
    "first_axle_offset": Param(2.5, "distance of the first axle behind the train front [m] (vehicle data)",
                               (0.0, 1000.0)),
    "last_axle_offset": Param(0.0, "distance of the last axle behind the front [m]; 0 = unknown: no fix while "
                                   "the train backs", (0.0, 1000.0)),
    "axle_offset_sigma": Param(0.02, "1-sigma of the configured axle offsets [m]", (0.0, 1.0)),
    "max_speed": Param(100.0, "decoder: highest train speed [m/s] for the timing part of a fix's stddev (UM71C "
                              "lines 300-350 km/h)", (1.0, 200.0)),
    "report_period": Param(1.0, "period of the SectionOccupancy report without state changes [s]",
                           (1.0e-3, 3600.0)),
    "faults": Param("", "injected faults separated by ';' (tests): 'ID@T0[-T1]:poor_shunt', 'ID@T:broken_rail', "
                        "'ID@T:tx_failed', 'ID@T0[-T1]:interference'"),
}

FAULT_KINDS = ("poor_shunt", "broken_rail", "tx_failed", "interference")


# ----------------------------------------------------------------------------------
# Circuits of a track
# ----------------------------------------------------------------------------------

def _carrier_of(system: str, group: str, given, n: int, cid: str) -> tuple[float, str]:
    """(nominal carrier [Hz], label) of the n-th circuit of a group, or of the given carrier."""
    if system == "UM71C":
        pair = UM71C_CARRIERS[group]
        if given is None:
            f = pair[n % 2]
        else:
            try:
                f = float(given)
            except (TypeError, ValueError):
                raise TrackError(f"{KIND} '{cid}': UM71C carrier {given!r} is not a frequency [Hz]") from None
            if f not in pair:
                raise TrackError(f"{KIND} '{cid}': UM71C carrier {f:g} Hz is not one of track {group} "
                                 f"({pair[0]:g} / {pair[1]:g} Hz, seed 004 Table 1)")
        return f, f"F{pair.index(f) + 1}"
    letters = TI21_PAIRS[group]
    if given is None:
        letter = letters[n % 2]
    elif str(given).upper() in TI21_FREQUENCIES:
        letter = str(given).upper()
    else:
        try:
            f = float(given)
        except (TypeError, ValueError):
            f = math.nan
        match = [k for k, v in TI21_FREQUENCIES.items() if v[0] == f]
        if not match:
            raise TrackError(f"{KIND} '{cid}': TI21 carrier {given!r} is no frequency type A-H or nominal "
                             "frequency of seed 004 Table 2")
        letter = match[0]
    if letter not in letters:
        raise TrackError(f"{KIND} '{cid}': TI21 frequency {letter} is not of pair {group} (seed 004 section 3.2: "
                         "one pair per track)")
    return TI21_FREQUENCIES[letter][0], letter


def circuit_table(track: Track | None, params: dict) -> list[dict]:
    """The track_circuit entries of a track (restricted to ``circuits``), sorted along it:
    dicts id, start, end, system, group (line / pair), carrier [Hz], label (F1/F2, A-H),
    band (low, high) [Hz] (TI21), spacing (capacitor spacing [m], 0 = none), zone [m],
    below / above (index of the touching neighbour or -1), section (the track's id), across_start /
    across_end (indices of the circuits of other sections joined at its start / end: none on one
    track; core/network/wayside.py ``network_circuits``). TrackError for a table that
    cannot be laid."""
    if track is None:
        return []
    out: list[dict] = []
    counters: dict[tuple[str, str], int] = {}
    for item in track.items(KIND):
        cid = str(item["id"])
        start, end = extent(KIND, item)
        system = str(item.get("system", "UM71C")).upper()
        if system not in SYSTEMS:
            raise TrackError(f"{KIND} '{cid}': system {system!r} is not one of {', '.join(SYSTEMS)}")
        if system == "UM71C":
            group = str(item.get("line", "T1")).upper()
            if group not in UM71C_CARRIERS:
                raise TrackError(f"{KIND} '{cid}': UM71C line {group!r} is not T1 or T2 (seed 004 Table 1)")
            zone = float(item.get("zone", params["zone_um71c"]))
        else:
            group = str(item.get("pair", "A/B")).upper().replace("-", "/")
            if len(group) == 2:
                group = group[0] + "/" + group[1]
            if group not in TI21_PAIRS:
                raise TrackError(f"{KIND} '{cid}': TI21 pair {group!r} is not one of {', '.join(TI21_PAIRS)}")
            zone = float(item.get("zone", params["zone_ti21"]))
        n = counters.get((system, group), 0)
        counters[system, group] = n + 1
        carrier, label = _carrier_of(system, group, item.get("carrier"), n, cid)
        if not (math.isfinite(start) and math.isfinite(end) and end - start > zone > 0.0):
            raise TrackError(f"{KIND} '{cid}': need end > start + zone ({start:g} .. {end:g} m, zone {zone:g} m)")
        if start < -1e-9 or end > track.length + 1e-9:
            raise TrackError(f"{KIND} '{cid}' ({start:g}..{end:g} m) is off the track (0..{track.length:g} m)")
        if out and start < out[-1]["end"] - 1e-6:
            raise TrackError(f"{KIND} '{cid}' overlaps '{out[-1]['id']}'")
        band = TI21_FREQUENCIES[label][1:] if system == "TI21" else (carrier, carrier)
        spacing = CAPACITOR_SPACING[carrier] if system == "UM71C" else 0.0
        out.append({"id": cid, "start": start, "end": end, "system": system, "group": group, "carrier": carrier,
                    "label": label, "band": band, "spacing": spacing, "zone": zone, "below": -1, "above": -1,
                    "section": track.track_id, "across_start": [], "across_end": []})
    for k in range(1, len(out)):
        if abs(out[k]["start"] - out[k - 1]["end"]) <= 1e-6:
            if out[k]["carrier"] == out[k - 1]["carrier"]:
                raise TrackError(f"{KIND} '{out[k - 1]['id']}' and '{out[k]['id']}' touch on the same carrier "
                                 f"{out[k]['carrier']:g} Hz (seed 004 section 3.1: neighbours differ)")
            out[k]["below"], out[k - 1]["above"] = k - 1, k
    wanted = [c.strip() for c in str(params.get("circuits", "")).split(",") if c.strip()]
    if wanted:
        known = {c["id"] for c in out}
        missing = [c for c in wanted if c not in known]
        if missing:
            raise TrackError(f"{KIND} {', '.join(missing)} not on track {track.track_id}")
        keep = [k for k, c in enumerate(out) if c["id"] in wanted]
        index = {old: new for new, old in enumerate(keep)}
        out = [dict(out[k], below=index.get(out[k]["below"], -1), above=index.get(out[k]["above"], -1))
               for k in keep]
    if not out:
        raise TrackError(f"no {KIND} on track {track.track_id}")
    if len({c["id"] for c in out}) != len(out):
        raise TrackError(f"{KIND} ids are not unique")
    return out


def channel_layout(circuits: list[dict]) -> tuple[tuple[str, ...], tuple[str, ...]]:
    names = tuple(f"{c['id']}.level" for c in circuits)
    return names, ("1",) * len(names)


def parse_faults(text: str, ids: list[str]) -> list[tuple[int, float, float, str]]:
    """[(circuit index, t0, t1, kind)] of 'ID@T0[-T1]:kind' entries (t1 = inf if not given)."""
    faults = []
    for entry in filter(None, (s.strip() for s in str(text or "").split(";"))):
        try:
            where, kind = entry.rsplit(":", 1)
            cid, span = where.split("@", 1)
            cid, kind = cid.strip(), kind.strip()
            if span.count("-") == 1 and not span.startswith("-"):
                t0, t1 = (float(v) for v in span.split("-"))
            else:
                t0, t1 = float(span), math.inf
        except ValueError:
            raise ValueError(f"malformed track circuit fault {entry!r}; expected 'ID@T0[-T1]:"
                             f"{'|'.join(FAULT_KINDS)}'") from None
        if kind not in FAULT_KINDS:
            raise ValueError(f"unknown track circuit fault kind {kind!r}; known: {', '.join(FAULT_KINDS)}")
        if cid not in ids:
            raise ValueError(f"track circuit fault names unknown circuit {cid!r}")
        faults.append((ids.index(cid), t0, t1, kind))
    return faults


# ----------------------------------------------------------------------------------
# Transmission line
# ----------------------------------------------------------------------------------

def _line(d: np.ndarray, g: complex, z0: complex) -> np.ndarray:
    """ABCD matrices (..., 2, 2) of uniform rail pieces of lengths d [m]."""
    gd = g * np.asarray(d, dtype=float)
    c, s = np.cosh(gd), np.sinh(gd)
    return np.stack([np.stack([c, z0 * s], -1), np.stack([s / z0, c], -1)], -2)


def _shunt(y) -> np.ndarray:
    """ABCD matrices (..., 2, 2) of shunt admittances y [S]."""
    y = np.asarray(y, dtype=complex)
    one, zero = np.ones_like(y), np.zeros_like(y)
    return np.stack([np.stack([one, zero], -1), np.stack([y, one], -1)], -2)


class CircuitLine:
    """One circuit's rails as a transmission line at its carrier: the transmitter at ``a``,
    the receiver at ``b`` (chainages [m]), lumped capacitors and an optional series break.

    ``voltages(x, r)`` gives the receiver voltage and the transmitter terminal voltage [V
    per V of source] for axles at chainages x (n samples x k axles, ascending along a row;
    axles off the span are ignored) with shunt resistances r (same shape)."""

    def __init__(self, circuit: dict, params: dict, ballast: float, broken: bool = False):
        f = circuit["carrier"]
        w = 2.0 * math.pi * f
        z = params["rail_resistance"] * math.sqrt(f / 2000.0) + 1j * w * params["rail_inductance"]
        y = 1.0 / (ballast * 1000.0)
        self.g, self.z0 = complex(np.sqrt(z * y)), complex(np.sqrt(z / y))
        half = 0.5 * circuit["zone"]
        self.a, self.b = circuit["start"] - half, circuit["end"] + half
        self.zs, self.zr = params["source_impedance"], params["receiver_impedance"]
        # fixed elements between cells: capacitors (shunt) and the break (series)
        elements: list[tuple[float, np.ndarray]] = []
        spacing, cap = circuit["spacing"], params["capacitor"]
        if spacing > 0.0 and cap > 0.0:
            for x in np.arange(circuit["start"] + 0.5 * spacing, circuit["end"], spacing):
                elements.append((float(x), _shunt(1j * w * cap)))
        if broken:
            series = np.array([[1.0, params["break_resistance"]], [0.0, 1.0]], dtype=complex)
            elements.append((0.5 * (circuit["start"] + circuit["end"]), series))
        elements.sort(key=lambda e: e[0])
        self.bounds = np.array([self.a] + [e[0] for e in elements] + [self.b])
        self.fixed = [e[1] for e in elements]
        self.cells = _line(np.diff(self.bounds), self.g, self.z0)
        eye = np.eye(2, dtype=complex)
        nc = len(self.cells)
        # prefix[j]: the chain up to the start of cell j; tail[j]: from the end of cell j
        # (its fixed element, if any) to the receiver
        self.prefix = [eye]
        for j in range(nc - 1):
            self.prefix.append(self.prefix[-1] @ self.cells[j] @ self.fixed[j])
        self.tail = [eye] * nc
        after = eye
        for j in range(nc - 1, -1, -1):
            self.tail[j] = (self.fixed[j] if j < len(self.fixed) else eye) @ after
            after = self.cells[j] @ self.tail[j]
        self.empty = self._terminals(after[None])

    def _terminals(self, m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(V_rx, V_tx) for chain matrices m (n, 2, 2): source 1 V behind zs, load zr."""
        a, b, c, d = m[:, 0, 0], m[:, 0, 1], m[:, 1, 0], m[:, 1, 1]
        k = a + b / self.zr
        v_rx = 1.0 / (k + self.zs * (c + d / self.zr))
        return v_rx, k * v_rx

    def voltages(self, x: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        n = x.shape[0]
        inside = (x > self.a) & (x < self.b)
        if not inside.any():
            return np.broadcast_to(self.empty[0], (n,)), np.broadcast_to(self.empty[1], (n,))
        # only the cells j0..j1 that hold an axle in some sample are multiplied out; the rest
        # of the chain is the cached prefix and tail
        cell = np.searchsorted(self.bounds, x[inside], side="right") - 1
        j0, j1 = int(cell.min()), int(cell.max())
        end = self.bounds[j1 + 1]
        fixed_pos = self.bounds[j0 + 1:j1 + 1]
        nf, k = fixed_pos.size, x.shape[1]
        eye = np.eye(2, dtype=complex)
        pos = np.concatenate([np.broadcast_to(fixed_pos, (n, nf)), np.where(inside, x, end)], axis=1)
        mats = np.empty((n, nf + k, 2, 2), dtype=complex)
        if nf:
            mats[:, :nf] = np.stack(self.fixed[j0:j1])[None]
        mats[:, nf:] = np.where(inside[..., None, None], _shunt(1.0 / r), eye)
        order = np.argsort(pos, axis=1, kind="stable")
        pos = np.take_along_axis(pos, order, axis=1)
        mats = np.take_along_axis(mats, order[..., None, None], axis=1)
        d = np.diff(np.concatenate([np.full((n, 1), self.bounds[j0]), pos, np.full((n, 1), end)], axis=1), axis=1)
        seq = np.empty((n, 2 * (nf + k) + 2, 2, 2), dtype=complex)
        seq[:, 0::2] = _line(d, self.g, self.z0)
        seq[:, 1::2][:, :-1] = mats
        seq[:, -1] = eye
        while seq.shape[1] > 1:   # ordered product, pairwise
            if seq.shape[1] % 2:
                seq = np.concatenate([seq, np.broadcast_to(eye, (n, 1, 2, 2))], axis=1)
            seq = seq[:, 0::2] @ seq[:, 1::2]
        return self._terminals(self.prefix[j0] @ seq[:, 0] @ self.tail[j1])


# ----------------------------------------------------------------------------------
# Simulator
# ----------------------------------------------------------------------------------

class TrackCircuitSimulator(Simulator):
    """The receivers of the track circuits of a track, shunted by every train's axles."""

    sensor = SENSOR
    sees_all_trains = True
    channels = ()  # per instance: one per circuit (the layout depends on the track)
    units = ()
    adc_lsb = {"1": 4.0 / 4096}  # 12-bit level over the 0..4 output range
    default_sample_rate = 100.0

    def __init__(self, *args):
        super().__init__(*args)
        p = self.params
        self.circuits = circuit_table(self.track, p)
        self.channels, self.units = channel_layout(self.circuits)
        self.faults = parse_faults(p["faults"], [c["id"] for c in self.circuits])
        self.lines = [CircuitLine(c, p, p["ballast_resistance"]) for c in self.circuits]
        broken = {ci for ci, _, _, kind in self.faults if kind == "broken_rail"}
        self.broken_lines = {ci: CircuitLine(self.circuits[ci], p, p["ballast_resistance"], broken=True)
                             for ci in broken}
        # receivers adjusted to level 1 with no train at the adjustment ballast resistance
        self.v_ref = np.array([abs(CircuitLine(c, p, p["adjust_ballast"]).empty[0][0]) for c in self.circuits])
        self.gain = np.maximum(0.1, 1.0 + self.rng.normal(0.0, p["adjust_sigma"], len(self.circuits)))
        self.offsets = np.sort(np.concatenate([np.asarray(v.axles, dtype=float) for v in self.fleet]))

    def axle_positions(self, position: np.ndarray) -> np.ndarray:
        """Axle chainages (n, k) of every train seen, ascending along each row."""
        return np.sort(np.concatenate(self.axle_chainages(position), axis=1), axis=1)

    def voltages(self, times: np.ndarray, position: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(V_rx, V_tx) of every circuit (n, circuits), complex, noise-free [V per V of source]."""
        n, nc = len(times), len(self.circuits)
        x = self.axle_positions(position) if len(self.offsets) else np.zeros((n, 0))
        r = np.full(x.shape, self.params["shunt_resistance"])
        for ci, t0, t1, kind in self.faults:
            if kind == "poor_shunt":
                line = self.lines[ci]
                on = ((times >= t0) & (times < t1))[:, None] & (x > line.a) & (x < line.b)
                r = np.where(on, self.params["poor_shunt_resistance"], r)
        v_rx = np.zeros((n, nc), dtype=complex)
        v_tx = np.zeros((n, nc), dtype=complex)
        for ci, line in enumerate(self.lines):
            broken = np.zeros(n, dtype=bool)
            for fi, t0, t1, kind in self.faults:
                if fi == ci and kind == "broken_rail":
                    broken |= times >= t0
            if broken.any():
                ok = ~broken
                if ok.any():
                    v_rx[ok, ci], v_tx[ok, ci] = line.voltages(x[ok], r[ok])
                v_rx[broken, ci], v_tx[broken, ci] = self.broken_lines[ci].voltages(x[broken], r[broken])
            else:
                v_rx[:, ci], v_tx[:, ci] = line.voltages(x, r)
            for fi, t0, t1, kind in self.faults:
                if fi == ci and kind == "tx_failed":
                    off = times >= t0
                    v_rx[off, ci] = 0.0
                    v_tx[off, ci] = 0.0
        return v_rx, v_tx

    def levels(self, times: np.ndarray, position: np.ndarray) -> np.ndarray:
        """Noise-free receiver levels (n, circuits) [1], interference included."""
        p = self.params
        v_rx, v_tx = self.voltages(times, position)
        own = np.abs(v_rx) / self.v_ref * self.gain
        leak2 = np.zeros_like(own)
        for ci, c in enumerate(self.circuits):
            nb = c["above"]   # the neighbour whose transmitter sits at this receiver's end
            if nb < 0:
                continue
            coupling = np.full(len(times), p["crosstalk"])
            for fi, t0, t1, kind in self.faults:
                if fi == ci and kind == "interference":
                    coupling = np.where((times >= t0) & (times < t1), p["interference_coupling"], coupling)
            leak2[:, ci] = (coupling * np.abs(v_tx[:, nb]) / self.v_ref[ci] * self.gain[ci]) ** 2
        return np.sqrt(own ** 2 + leak2)

    def samples(self, times, position, speed, acceleration):
        self.orientations(speed)
        lv = self.levels(times, position)
        sigma = self.params["noise_sigma"]
        n1 = self.rng.normal(0.0, sigma, lv.shape)
        n2 = self.rng.normal(0.0, sigma, lv.shape)
        return np.minimum(np.hypot(lv + n1, n2), self.params["adc_range"] - 4.0 / 4096)


# ----------------------------------------------------------------------------------
# Decoder
# ----------------------------------------------------------------------------------

class TrackCircuitDecoder(Decoder):
    sensor = SENSOR
    channels = ()  # layout depends on the track: checked in decode()

    def __init__(self, params: dict, track: Track):
        super().__init__(params, track)
        p = params
        if p["threshold_drop"] >= p["threshold_pick"]:
            raise ValueError("threshold_drop must be below threshold_pick")
        self.circuits = self.circuit_layout(track, p)
        self.expected, _ = channel_layout(self.circuits)
        self.ids = [c["id"] for c in self.circuits]
        nc = len(self.circuits)
        self.low = np.zeros(nc, dtype=bool)          # hysteresis: level low
        self.edge = np.full(nc, -math.inf)           # time of the last hysteresis edge (onset) [s]
        self.state = [CLEAR] * nc
        self.entered: list[float | None] = [None] * nc   # onset of the hand-over into each circuit [s]
        self.moving = [0] * nc     # direction of the hand-over into each circuit, along its chainage (0: none)
        self.orient = int(np.sign(p["orientation"])) or None
        self._reported: tuple | None = None
        self._last_report: float | None = None
        self._force_report = True
        self._fs = 1.0
        self.stats.update(drops=0, picks=0, fixes=0, train_lost=0, fix_withheld=0)

    def circuit_layout(self, track: Track, params: dict) -> list[dict]:
        """The circuits this decoder watches (``circuit_table``; a network's device: every section's)."""
        return circuit_table(track, params)

    # -- public API -------------------------------------------------------------------
    def reset_section(self, section_id: str) -> None:
        """Operator reset of a DISTURBED circuit: its state follows its receiver again
        (OCCUPIED if its level is low). KeyError for an unknown id."""
        if section_id not in self.ids:
            raise KeyError(f"unknown circuit {section_id!r}; known: {', '.join(self.ids)}")
        k = self.ids.index(section_id)
        self.state[k] = OCCUPIED if self.low[k] else CLEAR
        self._force_report = True

    def occupancy(self, stamp: float) -> SectionOccupancy:
        return SectionOccupancy(float(stamp), self.unit_id, tuple(
            SectionState(c["id"], float(c["start"]), float(c["end"]), self.state[k], 0, 0, 0)
            for k, c in enumerate(self.circuits)))

    # -- decoding ---------------------------------------------------------------------
    def _check(self, block: RawBlock) -> np.ndarray:
        if block.channels != self.expected:
            known = set(self.ids)
            for name in block.channels:
                cid, _, what = name.rpartition(".")
                if cid not in known or what != "level":
                    raise InputRejected("unknown_id", f"channel {name!r} is not a circuit of this device")
            raise InputRejected("channels", f"channels {block.channels} differ from {self.expected}")
        x = block.data
        lo, hi = float(x.min()), float(x.max())
        if lo < -1.0 or hi > self.params["adc_range"]:
            raise InputRejected("implausible", f"receiver level {lo:g} .. {hi:g} outside -1 .. "
                                f"{self.params['adc_range']:g}")
        return x

    def decode(self, block: RawBlock):
        x = self._check(block)
        p = self.params
        self._fs = block.sample_rate
        dt = 1.0 / block.sample_rate
        t0 = block.t0
        n = x.shape[0]
        out = []
        if self._force_report or self._last_report is None:
            out.append(self.occupancy(t0))
            self._reported = tuple(self.state)
            self._last_report = t0
            self._force_report = False
        drop, pick = p["threshold_drop"], p["threshold_pick"]
        # fast path: no hysteresis edge and no pending delay in the block
        steady = all((not low and mn >= drop and st == CLEAR) or (low and mx <= pick and st != CLEAR)
                     for low, mn, mx, st in zip(self.low.tolist(), x.min(axis=0).tolist(),
                                                x.max(axis=0).tolist(), self.state))
        if not steady:
            for i in range(n):
                t = t0 + i * dt
                for k in range(len(self.circuits)):
                    v = float(x[i, k])
                    if not self.low[k] and v < drop:
                        self.low[k], self.edge[k] = True, t
                    elif self.low[k] and v > pick:
                        self.low[k], self.edge[k] = False, t
                    if self.low[k] and self.state[k] == CLEAR and t - self.edge[k] >= p["drop_delay"] - 1e-9:
                        out.extend(self._dropped(k, t))
                    elif not self.low[k] and self.state[k] == OCCUPIED \
                            and t - self.edge[k] >= p["pickup_delay"] - 1e-9:
                        self._picked(k, t)
                    if tuple(self.state) != self._reported:
                        out.append(self.occupancy(t))
                        self._reported = tuple(self.state)
                        self._last_report = t
        t_last = t0 + (n - 1) * dt
        if t_last - self._last_report >= p["report_period"] - 1e-9:
            out.append(self.occupancy(t_last))
            self._last_report = t_last
        return out

    def _busy(self, k: int) -> bool:
        return k >= 0 and (bool(self.low[k]) or self.state[k] != CLEAR)

    def _dropped(self, k: int, t: float) -> list:
        """Circuit k decided OCCUPIED at t: a hand-over from a neighbour gives a boundary fix."""
        self.state[k] = OCCUPIED
        self.stats["drops"] += 1
        c = self.circuits[k]
        behind = [(nb, d) for nb, d in _neighbours(c) if self.state[nb] == OCCUPIED]
        if len(behind) != 1:
            return []
        nb, d = behind[0]
        across = self.circuits[nb]["section"] != c["section"]
        t_on = float(self.edge[k])
        entered, self.entered[k] = self.entered[nb], None
        if entered is not None:
            cb = self.circuits[nb]
            if t_on - entered < (cb["end"] - cb["start"] - cb["zone"]) / self.params["max_speed"]:
                # the train that entered the neighbour cannot have crossed it yet: not a hand-over
                # (a broken rail, a failed transmitter ahead of the train)
                self.stats["fix_withheld"] += 1
                return []
        self.entered[k] = t_on
        self.moving[k] = d
        if self.params["front_first"]:
            o = d
        else:
            if self.orient is None:
                self.orient = d
            o = self.orient
        offset = self.params["first_axle_offset"] if d == o else self.params["last_axle_offset"]
        if d != o and offset <= 0.0:
            self.stats["fix_withheld"] += 1
            return []
        p = self.params
        sigma = fix_sigma(p, c["zone"], self._fs)
        self.stats["fixes"] += 1
        return [PositionFix(t_on, self.sensor, self.unit_id, c["section"], joint_id(self.circuits[nb], c, d),
                            fix_position(c, d, o * offset, insulated=across), sigma, int(d))]

    def _picked(self, k: int, t: float) -> None:
        """Circuit k decided CLEAR at t: if no neighbour holds the train, it was lost."""
        self.state[k] = CLEAR
        self.entered[k] = None
        moving, self.moving[k] = self.moving[k], 0
        self.stats["picks"] += 1
        c = self.circuits[k]
        sides = _neighbours(c)
        if not sides or any(self._busy(nb) for nb, _ in sides):
            return
        # the neighbours ahead of the train that handed over into k (beyond its end when it entered
        # at its start: entry direction +1); both sides when no hand-over was seen
        lost = [nb for nb, d in sides if not moving or d != moving]
        if lost:
            self.stats["train_lost"] += 1
            for nb in lost:
                self.state[nb] = DISTURBED


def _neighbours(c: dict) -> list[tuple[int, int]]:
    """(index, direction of a train entering ``c`` from it) of every circuit touching ``c``: at its
    start (entered along its chainage, +1) and at its end (-1), on its track and across nodes."""
    return ([(nb, 1) for nb in (c["below"], *c["across_start"]) if nb >= 0]
            + [(nb, -1) for nb in (c["above"], *c["across_end"]) if nb >= 0])


def joint_id(left: dict, entered: dict, direction: int) -> str:
    """Reference id of the hand-over from circuit ``left`` into ``entered`` (entered in
    ``direction`` along its chainage): on one track 'BELOW/ABOVE' in chainage order, whichever
    way; across a node (the two circuits on different sections) 'LEFT/ENTERED', one id per
    direction, since its fixes lie on the entered circuit's section."""
    if left["section"] != entered["section"]:
        return f"{left['id']}/{entered['id']}"
    return f"{left['id']}/{entered['id']}" if direction > 0 else f"{entered['id']}/{left['id']}"


def fix_position(circuit: dict, direction: int, axle: float, insulated: bool = False) -> float:
    """Train-front chainage [m] of a boundary fix of ``circuit`` entered in ``direction`` (+1:
    at its start, -1: at its end): the entering axle shunts the new circuit down where its line
    begins, the tuned unit at the near edge of the zone, half a zone before the boundary (at an
    ``insulated`` joint, where two sections meet at a node: the boundary itself); the front is
    ``axle`` [m] (o x the axle's offset behind the front) beyond that."""
    boundary = circuit["start"] if direction > 0 else circuit["end"]
    drop_point = boundary - (0.0 if insulated else direction * 0.5 * circuit["zone"])
    return float(drop_point + axle)


def fix_sigma(params: dict, zone: float, sample_rate: float) -> float:
    """1-sigma [m] of a boundary fix at a tuned zone of ``zone`` [m] with levels sampled at
    ``sample_rate`` [Hz]: half the zone persistent and a quarter white, the axle offset and the
    timing (``max_speed`` x a sample / sqrt 12)."""
    timing = params["max_speed"] / sample_rate / math.sqrt(12.0)
    return math.sqrt(1.25 * (0.5 * zone) ** 2 + params["axle_offset_sigma"] ** 2 + timing ** 2)


def boundary_windows(params: dict, circuits: list[dict]) -> dict[str, ReferenceWindow]:
    """Reference id 'BELOW/ABOVE' of every joint of ``circuits`` -> the chainages [m] of its
    fixes (``fix_position``): the circuit above entered upwards, the one below downwards, the
    front ``first_axle_offset`` ahead of the axle, or ``last_axle_offset`` behind it for a
    backing train (only if set and not ``front_first``: else the decoder gives no such fix)."""
    axles = [params["first_axle_offset"]]
    if params["last_axle_offset"] > 0.0 and not params["front_first"]:
        axles.append(-params["last_axle_offset"])
    points: dict[str, list[float]] = {}
    for entered in circuits:
        for nb, d in _neighbours(entered):
            left = circuits[nb]
            insulated = left["section"] != entered["section"]
            points.setdefault(joint_id(left, entered, d), []).extend(
                fix_position(entered, d, d * a, insulated) for a in axles)
    return {ref: ReferenceWindow(min(xs), max(xs)) for ref, xs in points.items()}


def error_model(params: dict, track, vehicle) -> ErrorModel:
    """Boundary fixes for the fusion: the detection point within the tuned zone is a
    persistent error of the equipment (the same side of the boundary for every hand-over
    in one direction), carried as a fix bias of half the longest zone and included in the
    reported stddev; fault mode: a miscount (a circuit dropping with no train ahead of
    a train, a broken rail, gives a wrong boundary). Floor: the decoder's ``fix_sigma`` at
    the shortest zone and the configured sample rate (the pipeline refuses another).
    References: every joint of the device's circuits, windows ``boundary_windows``."""
    circuits = circuit_table(track, params) if track is not None and track.items(KIND) else []
    zone = max((c["zone"] for c in circuits), default=max(params["zone_um71c"], params["zone_ti21"]))
    shortest = min((c["zone"] for c in circuits), default=min(params["zone_um71c"], params["zone_ti21"]))
    rate = float(params.get("sample_rate") or TrackCircuitSimulator.default_sample_rate)
    references = ReferenceTable(boundary_windows(params, circuits)) if track is not None else None
    return ErrorModel(SENSOR, "position", fix_bias_sigma=0.5 * zone, reported_fix_bias=0.5 * zone,
                      faults=("miscount", "offset"), min_stddev=fix_sigma(params, shortest, rate), references=references)


SPEC = SensorSpec(
    node="track_circuit_receiver", sensor=SENSOR, simulator=TrackCircuitSimulator, decoder=TrackCircuitDecoder,
    params=PARAMS, description="wayside AF jointless track circuits UM71C / TI21: section occupancy and coarse "
                               "train-front fixes at the circuit boundaries",
    seeds=("004",), outputs=("position", "sections"), error_model=error_model,
)
