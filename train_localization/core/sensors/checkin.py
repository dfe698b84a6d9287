"""HF check-in / check-out block detection (HSST, Kobe Port Island line), seeds 000 and 002.

Principle (seed 000 section 2.2.1, section 3.2; seed 002 section 2.1.1): train detection for
train protection by "continuous high-frequency check-in / check-out": a loop circuit laid
in every block receives, continuously, the HF signals of transmitting antennas at the
front and the rear of the train. On the ground the check-in signal (front) is stored when
it is received, and released when the check-out signal (rear) has been received: the block
is occupied from the front's check-in until the rear's check-out, so the unit of detection
is the block (seed 000 section 2.2.1: the loop is shared with the ATC transmission path).

Physics of the raw signal (assumptions: the seeds give no frequencies, heights or levels):
  * each block's loop is a long, flat wire loop along the guideway from its ``start`` to its
    ``end``; an on-board antenna at height ``antenna_height`` h above the loop couples to it
    through the field of the loop's wires. Far inside the loop the coupling is constant; at a
    loop end the flux of a small antenna through the loop changes like the field of the end
    conductor (a long straight wire): with u the antenna's distance inside the end,
    c(u) = 1/2 + atan(u / h) / pi. A loop from s0 to s1 couples
        c(a) = (atan((a - s0) / h) + atan((s1 - a) / h)) / pi
    to an antenna at chainage a: 1 inside, 1/2 at a boundary, falling like h / (pi |u|)
    outside. Adjacent loops meet at the boundary, so the two loops see a passing antenna
    cross over there.
  * the loops are laid with their ends off the surveyed boundaries by ``boundary_sigma``
    (the same shift for the two loops meeting at a boundary);
  * the HF signal travels along the loop to the receiver at the loop's ``start``: an
    attenuation of ``loop_attenuation`` dB/km from the antenna's place to the receiver;
  * the front transmitter sends the check-in carrier ``f_checkin``, the rear one the
    check-out carrier ``f_checkout``; each block's receiver has a band filter and detector
    per carrier. Its level [1] is normalised to 1 for an antenna in the middle of a loop
    of the adjustment length (the receiver's gain, error ``adjust_sigma`` per receiver and
    carrier); several antennas on one carrier add in power (unsynchronised oscillators);
    Gaussian noise ``noise_sigma`` on both quadratures of the detected carrier.

Several trains: ``loop_levels(loops, params, fronts, rears, ...)`` takes the antenna
chainages of any number of trains (one (n,) array per train and end) and returns the
levels of every loop; the Simulator feeds it the one scenario train, a multi-train
simulation the chainages of all of them.

Track equipment (kind ``checkin_block``), one entry per block and its loop::

    checkin_block:
      - {id: B01, start: 0.0, end: 300.0}
      - {every: 300.0, start: 300.0, end: 5400.0, id: "B{n:02d}", length: 300.0}

Blocks must not overlap; touching blocks (end == next start) are neighbours.

Raw signal: channels ``<id>.in`` and ``<id>.out`` [1] per block: the detected levels of the
check-in and the check-out carrier, default 200 Hz (the detector's output is a slow signal).

Faults (``faults``, ';'-separated, times in s): ``rear@T0[-T1]:tx_failed`` (the rear
transmitter is silent: the block the train leaves is never checked out and stays OCCUPIED,
the safe side), ``front@T0[-T1]:tx_failed`` (no check-in: a block the train enters is
occupied only once the rear's check-out carrier is received there), ``ID@T0[-T1]:noise_burst``
(broadband interference in block ID's loop, ``burst_level``, raises both detectors).

Decoder: per block and carrier a hysteresis (present above ``threshold_on``, absent again
below ``threshold_off``) and a confirmation time ``confirm_time`` (an edge is taken when the
level stayed beyond the threshold that long; its stamp is the onset, interpolated between
the samples). Per block a count of stored check-ins and the detailed state:
  * CHECKED_IN: the front's carrier is received (the train head is in the block);
  * CHECKED_OUT: the rear's carrier is received (the tail is in the block);
  * OCCUPIED: a check-in is stored, neither carrier is received (the body spans the block);
  * CLEAR: no check-in stored, no carrier received.
A check-in (the front's carrier appears) stores one check-in; a check-out releases one: the
rear's carrier disappears from the block and the block ahead (running direction
``orientation``) receives it, at once or within ``handover_time`` (the tail has passed the
boundary; a carrier that vanishes inside the block, a failed rear transmitter, releases
nothing); at the end of the equipped blocks the disappearance alone. The rear's carrier
appearing in a block with nothing stored stores one too (the train is there, whatever the
front said: ``stats["checkout_without_checkin"]``). Both carriers appearing within
``burst_window`` of each other in one block (an appearance is taken that long after its
onset at the earliest) is interference, not a train (a front and a rear cannot enter
together): the edges are ignored until both are gone, the block reads OCCUPIED meanwhile
(``stats["noise_bursts"]``). At start the levels set the states: a block receiving either
carrier holds a check-in, and so do the blocks between a block receiving the front's and
one receiving the rear's carrier (the body).
Outputs:
  * SectionOccupancy (source = unit id) of every block at the first block, on every change
    and every ``report_period``: state OCCUPIED for CHECKED_IN, OCCUPIED and CHECKED_OUT
    (the message's states), axle_count = stored check-ins, axles_in / axles_out = the
    check-ins and check-outs counted; ``block_states`` holds the detailed states;
  * boundary fix: a check-in while a neighbouring block receives the front's carrier, or lost
    it within ``handover_time`` of the onset (the hand-over at the boundary), gives a
    PositionFix of the train front: the boundary, plus the distance inside the new loop at
    which its level reaches ``threshold_on`` (the nominal coupling curve), plus
    ``front_antenna_offset``, stamped at the onset; 1-sigma from the boundary's installation
    error and the receiver's gain error (persistent per boundary: the error model's fix bias,
    a new one per boundary), the antenna
    height's tolerance, the onset's timing (``max_speed`` x a sample / sqrt 12) and the
    offset's tolerance. No fix without a hand-over (a burst, the first block, a train
    appearing), nor for a front antenna that trails (a train backing);
  * integrity: each check-out handed over to the block ahead confirms that the tail followed
    the head (``stats["integrity_confirmed"]``); a block still holding a check-in when the
    front checks in farther than ``max_train_length`` beyond it has missed its check-out (a
    failed rear transmitter): it stays OCCUPIED and is counted once
    (``stats["checkout_missing"]``, ``missing_checkout`` lists the blocks).

Not modelled: the ATC telegrams sharing the loop (seed 000 section 2.2.1), crossovers in
the loop, loops that overlap at the boundaries, a train reversing inside a block (its
front carrier then leaves the block backwards: the block stays occupied, the safe side).
"""
from __future__ import annotations

import math

import numpy as np

from ..measurements import CLEAR, OCCUPIED, PositionFix, SectionOccupancy, SectionState
from ..signals import InputRejected, RawBlock
from ..track import Track, TrackError, extent
from .base import MIN_FIX_SIGMA, Decoder, ErrorModel, Param, ReferenceTable, ReferenceWindow, SensorSpec, Simulator

KIND = "checkin_block"
SENSOR = "checkin"
# detailed block states (decoder.block_states); the message carries CLEAR / OCCUPIED
CHECKED_IN, CHECKED_OUT = 3, 4
CARRIERS = ("in", "out")

PARAMS = {
    "f_checkin": Param(10.0e3, "carrier of the front (check-in) transmitter [Hz] (assumption: seeds 000/002 give "
                               "only 'high frequency'; the receiver separates the carriers by its band filters)",
                       (1.0e3, 1.0e7)),
    "f_checkout": Param(12.0e3, "carrier of the rear (check-out) transmitter [Hz] (assumption)", (1.0e3, 1.0e7)),
    "antenna_height": Param(0.2, "height of the on-board antennas above the block loop's wires [m] (assumption); "
                                 "the width of the level's transition at a loop end", (0.02, 2.0)),
    "height_sigma": Param(0.02, "1-sigma variation of that height [m] (levitation gap, load; assumption)",
                          (0.0, 0.5)),
    "front_antenna_offset": Param(0.0, "distance of the front (check-in) antenna behind the train front [m] "
                                       "(seed 000 section 2.2.1: antennas at the front and the rear of the train)",
                                  (0.0, 1000.0)),
    "rear_antenna_offset": Param(0.0, "distance of the rear (check-out) antenna ahead of the train's tail [m] "
                                      "(seed 000 section 2.2.1); the tail is released that much minus "
                                      "the onset depth inside the block", (0.0, 1000.0)),
    "offset_sigma": Param(0.02, "1-sigma of the configured antenna offset [m]", (0.0, 1.0)),
    "boundary_sigma": Param(0.05, "1-sigma installation error of a loop end (a block boundary) against its chainage "
                                  "in the track file [m] (assumption: cable laid in the guideway, surveyed to "
                                  "+-0.15 m = 3 sigma); the loops on both sides of a boundary share it",
                            (0.0, 10.0)),
    "loop_attenuation": Param(2.0, "attenuation of the HF signal along a block loop towards its receiver at the "
                                   "loop's start [dB/km] (assumption)", (0.0, 100.0)),
    "adjust_length": Param(300.0, "loop length at which a receiver's level is adjusted to 1 for an antenna at the "
                                  "loop's middle [m] (assumption)", (1.0, 10000.0)),
    "adjust_sigma": Param(0.03, "1-sigma error of a receiver's adjusted gain per carrier [fraction] (assumption)",
                          (0.0, 0.5)),
    "noise_sigma": Param(0.02, "1-sigma noise of each quadrature of a detected carrier [1] (assumption)",
                         (0.0, 1.0)),
    "burst_level": Param(1.5, "level of the interference in a 'noise_burst' fault on both detectors [1] "
                              "(assumption: broadband, e.g. a traction arc)", (0.0, 10.0)),
    "faults": Param("", "faults: 'rear@T0[-T1]:tx_failed', 'front@T0[-T1]:tx_failed', 'ID@T0[-T1]:noise_burst', "
                        "';'-separated, times [s]"),
    "blocks": Param("", "comma-separated block ids of this device; empty = all blocks of the track"),
    "orientation": Param(1, "+1: train front faces increasing chainage, -1: decreasing [1]", (-1, 1)),
    "threshold_on": Param(0.6, "decoder: level above which a carrier is received [1] (fraction of the adjusted "
                               "level; assumption)", (0.0, 10.0)),
    "threshold_off": Param(0.4, "decoder: level below which it is lost again (hysteresis) [1] (assumption)",
                           (0.0, 10.0)),
    "confirm_time": Param(0.05, "decoder: time a level must stay beyond a threshold before the edge is taken [s] "
                                "(against noise; assumption)", (0.0, 60.0)),
    "handover_time": Param(5.0, "decoder: the front's carrier lost by a neighbouring block within this time of "
                                "its check-in is a hand-over at the boundary [s] (a creeping train; assumption)",
                           (0.0, 600.0)),
    "burst_window": Param(0.2, "decoder: both carriers appearing within this time in one block are interference "
                               "[s] (a train's front and rear cannot enter together; assumption)", (0.0, 60.0)),
    "max_train_length": Param(200.0, "decoder: longest train [m]: a block farther behind a check-in that still "
                                     "holds a check-in has missed its check-out", (1.0, 5000.0)),
    "max_speed": Param(30.0, "decoder: highest train speed [m/s] for the timing part of a fix's stddev (HSST "
                             "urban lines: 100-110 km/h; assumption)", (0.1, 200.0)),
    "report_period": Param(1.0, "decoder: period of the SectionOccupancy report without a change [s]",
                           (0.01, 3600.0)),
    "adc_range": Param(4.0, "detector output range [1]; a level beyond it (or below -1) is implausible",
                       (0.5, 100.0)),
}

DEFAULT_SAMPLE_RATE = 200.0


# ----------------------------------------------------------------------------------
# Equipment and physics (shared by the simulator, the decoder and tests)
# ----------------------------------------------------------------------------------

def block_table(track: Track, params: dict) -> list[dict]:
    """The blocks of the device: dicts id, start, end, below, above (neighbour indices or -1),
    sorted by chainage. TrackError for no blocks, an empty or overlapping block, an unknown id."""
    items = track.items(KIND)
    if not items:
        raise TrackError(f"track '{track.track_id}' has no {KIND} equipment")
    blocks = []
    for item in items:
        start, end = extent(KIND, item)
        if not end > start:
            raise TrackError(f"{KIND} '{item['id']}': end {end} must be beyond start {start}")
        blocks.append({"id": item["id"], "start": start, "end": min(end, track.length)})
    blocks.sort(key=lambda b: b["start"])
    for a, b in zip(blocks, blocks[1:]):
        if b["start"] < a["end"] - 1e-6:
            raise TrackError(f"{KIND}: blocks '{a['id']}' and '{b['id']}' overlap")
    wanted = [s.strip() for s in str(params.get("blocks", "")).split(",") if s.strip()]
    if wanted:
        ids = {b["id"] for b in blocks}
        unknown = sorted(set(wanted) - ids)
        if unknown:
            raise TrackError(f"{KIND}: unknown block ids {unknown}")
        blocks = [b for b in blocks if b["id"] in wanted]
    for k, b in enumerate(blocks):
        b["below"] = k - 1 if k > 0 and abs(blocks[k - 1]["end"] - b["start"]) < 1e-6 else -1
        b["above"] = k + 1 if k + 1 < len(blocks) and abs(blocks[k + 1]["start"] - b["end"]) < 1e-6 else -1
    return blocks


def channel_layout(blocks: list[dict]) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """Channel names (``<id>.in``, ``<id>.out`` per block) and units."""
    names = tuple(f"{b['id']}.{c}" for b in blocks for c in CARRIERS)
    return names, ("1",) * len(names)


def coupling(a: np.ndarray, start: float, end: float, height) -> np.ndarray:
    """Coupling [1] of antennas at chainages ``a`` [m] (any shape) to a loop from ``start`` to
    ``end`` at ``height`` [m] above it: (atan((a - start) / h) + atan((end - a) / h)) / pi."""
    return (np.arctan((a - start) / height) + np.arctan((end - a) / height)) / math.pi


def onset_depth(threshold: float, height: float) -> float:
    """Distance [m] inside a loop end at which the coupling of a long loop reaches ``threshold``
    (the end conductor alone: 1/2 + atan(u / h) / pi = threshold)."""
    return height * math.tan(math.pi * (threshold - 0.5))


def _attenuation(a: np.ndarray, block: dict, params: dict) -> np.ndarray:
    """Amplitude factor of the loop's attenuation from chainage a to the receiver at the start."""
    d = np.clip(a - block["start"], 0.0, block["end"] - block["start"])
    return 10.0 ** (-params["loop_attenuation"] * d / 20.0e3)


def loop_levels(blocks: list[dict], params: dict, fronts: list[np.ndarray], rears: list[np.ndarray],
                gains: np.ndarray | None = None, heights: np.ndarray | None = None) -> np.ndarray:
    """Noise-free detector levels (n, 2 x blocks) [1], channels as ``channel_layout``, of the
    block loops receiving the front antennas ``fronts`` (check-in carrier) and the rear antennas
    ``rears`` (check-out carrier) of any number of trains: one (n,) array of chainages [m] per
    train and end (NaN: that transmitter is silent). ``gains`` (blocks, 2): the receivers' gains
    (default 1); ``heights`` (n,): the antenna height [m] (default the parameter)."""
    n = len(fronts[0]) if fronts else len(rears[0]) if rears else 0
    nb = len(blocks)
    h = params["antenna_height"] if heights is None else heights
    ref = float(coupling(np.array(0.5 * params["adjust_length"]), 0.0, params["adjust_length"],
                         params["antenna_height"])) * 10.0 ** (-params["loop_attenuation"]
                                                                * 0.5 * params["adjust_length"] / 20.0e3)
    out = np.zeros((n, 2 * nb))
    for k, b in enumerate(blocks):
        for c, antennas in enumerate((fronts, rears)):
            power = np.zeros(n)
            for a in antennas:
                a = np.asarray(a, dtype=float)
                on = np.isfinite(a)
                if not on.any():
                    continue
                aa = np.where(on, a, b["start"] - 1.0e6)
                lv = coupling(aa, b["start"], b["end"], h) * _attenuation(aa, b, params)
                power += np.where(on, lv, 0.0) ** 2
            g = 1.0 if gains is None else gains[k, c]
            out[:, 2 * k + c] = g * np.sqrt(power) / ref
    return out


def parse_faults(text: str, ids: list[str]) -> list[tuple[str, float, float, str]]:
    """(target, t0, t1, kind): target 'front', 'rear' (tx_failed) or a block id (noise_burst)."""
    faults = []
    for part in str(text or "").split(";"):
        part = part.strip()
        if not part:
            continue
        try:
            where, rest = part.split("@", 1)
            when, kind = rest.split(":", 1)
            t0s, _, t1s = when.partition("-")
            t0, t1 = float(t0s), float(t1s) if t1s else math.inf
        except ValueError:
            raise ValueError(f"checkin fault {part!r}: expected TARGET@T0[-T1]:KIND") from None
        where, kind = where.strip(), kind.strip()
        if kind == "tx_failed" and where not in ("front", "rear"):
            raise ValueError(f"checkin fault {part!r}: tx_failed needs target 'front' or 'rear'")
        if kind == "noise_burst" and where not in ids:
            raise ValueError(f"checkin fault {part!r}: unknown block {where!r}")
        if kind not in ("tx_failed", "noise_burst"):
            raise ValueError(f"checkin fault {part!r}: kind must be tx_failed or noise_burst")
        faults.append((where, t0, t1, kind))
    return faults


# ----------------------------------------------------------------------------------
# Simulator
# ----------------------------------------------------------------------------------

class CheckinSimulator(Simulator):
    """The block loops' receivers, seeing the front and rear transmitters of the scenario train."""

    sensor = SENSOR
    channels = ()   # per instance: two per block
    units = ()
    adc_lsb = {"1": 4.0 / 4096}   # 12-bit detector output over 0..4
    default_sample_rate = DEFAULT_SAMPLE_RATE

    def __init__(self, *args):
        super().__init__(*args)
        p = self.params
        self.blocks = block_table(self.track, p)
        self.channels, self.units = channel_layout(self.blocks)
        self.faults = parse_faults(p["faults"], [b["id"] for b in self.blocks])
        # the loops as laid: each boundary off its surveyed chainage, the same for both loops at it
        edges = sorted({round(b[e], 6) for b in self.blocks for e in ("start", "end")})
        shift = dict(zip(edges, self.rng.normal(0.0, p["boundary_sigma"], len(edges))))
        self.laid = [{**b, "start": b["start"] + shift[round(b["start"], 6)],
                      "end": b["end"] + shift[round(b["end"], 6)]} for b in self.blocks]
        self.gains = np.maximum(0.1, 1.0 + self.rng.normal(0.0, p["adjust_sigma"], (len(self.blocks), 2)))
        self.orient = int(p["orientation"]) or 1

    def antennas(self, times: np.ndarray, position: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(front antenna, rear antenna) chainages [m] of the train; NaN while a transmitter fails."""
        p, o = self.params, self.orient
        front = position - o * p["front_antenna_offset"]
        rear = position - o * (self.vehicle.length - p["rear_antenna_offset"])
        for target, t0, t1, kind in self.faults:
            if kind == "tx_failed":
                off = (times >= t0) & (times < t1)
                if target == "front":
                    front = np.where(off, np.nan, front)
                else:
                    rear = np.where(off, np.nan, rear)
        return front, rear

    def samples(self, times, position, speed, acceleration):
        p = self.params
        front, rear = self.antennas(times, position)
        heights = np.maximum(0.2 * p["antenna_height"],
                             p["antenna_height"] + self.rng.normal(0.0, p["height_sigma"]) * np.ones(len(times)))
        lv = loop_levels(self.laid, p, [front], [rear], self.gains, heights)
        n1 = self.rng.normal(0.0, p["noise_sigma"], lv.shape)
        n2 = self.rng.normal(0.0, p["noise_sigma"], lv.shape)
        ids = [b["id"] for b in self.blocks]
        for target, t0, t1, kind in self.faults:
            if kind == "noise_burst":
                on = (times >= t0) & (times < t1)
                k = ids.index(target)
                n1[on, 2 * k:2 * k + 2] += p["burst_level"]
        return np.minimum(np.hypot(lv + n1, n2), p["adc_range"] - 4.0 / 4096)


# ----------------------------------------------------------------------------------
# Decoder
# ----------------------------------------------------------------------------------

class CheckinDecoder(Decoder):
    sensor = SENSOR
    channels = ()   # layout depends on the track: checked in decode()

    def __init__(self, params: dict, track: Track):
        super().__init__(params, track)
        p = params
        if p["threshold_off"] >= p["threshold_on"]:
            raise ValueError("threshold_off must be below threshold_on")
        if not 0.5 < p["threshold_on"] < 1.0:
            raise ValueError("threshold_on must lie between 0.5 (a boundary) and 1 (inside a loop)")
        self.blocks = block_table(track, p)
        self.expected, _ = channel_layout(self.blocks)
        self.ids = [b["id"] for b in self.blocks]
        nb = len(self.blocks)
        self.up = np.zeros((nb, 2), dtype=bool)        # hysteresis: level above threshold_on
        self.edge = np.full((nb, 2), -math.inf)         # onset of the last hysteresis edge [s]
        self.present = np.zeros((nb, 2), dtype=bool)    # confirmed: carrier received
        self.lost = np.full((nb, 2), -math.inf)         # onset of the last disappearance [s]
        self.leaving = [-math.inf] * nb                 # onset of the rear's carrier leaving, not yet handed over
        self.stored = [0] * nb                          # check-ins stored
        self.burst = [False] * nb                       # interference: edges ignored until both gone
        self.block_states = [CLEAR] * nb
        self.checkins = [0] * nb
        self.checkouts = [0] * nb
        self.missing_checkout: list[str] = []
        self._missing = [False] * nb
        self.orient = int(p["orientation"]) or 1
        self._started = False
        self._prev: np.ndarray | None = None            # last samples of the previous block
        self._reported: tuple | None = None
        self._last_report: float | None = None
        self._fs = DEFAULT_SAMPLE_RATE
        self.stats.update(checkins=0, checkouts=0, fixes=0, noise_bursts=0, integrity_confirmed=0,
                          checkout_missing=0, checkout_without_checkin=0)

    # -- public API -------------------------------------------------------------------
    def occupancy(self, stamp: float) -> SectionOccupancy:
        return SectionOccupancy(float(stamp), self.unit_id, tuple(
            SectionState(b["id"], float(b["start"]), float(b["end"]),
                         CLEAR if self.block_states[k] == CLEAR else OCCUPIED,
                         int(self.stored[k]), int(self.checkins[k]), int(self.checkouts[k]))
            for k, b in enumerate(self.blocks)))

    # -- decoding ---------------------------------------------------------------------
    def _check(self, block: RawBlock) -> np.ndarray:
        if block.channels != self.expected:
            known = set(self.ids)
            for name in block.channels:
                bid, _, what = name.rpartition(".")
                if bid not in known or what not in CARRIERS:
                    raise InputRejected("unknown_id", f"channel {name!r} is not a block loop of this device")
            raise InputRejected("channels", f"channels {block.channels} differ from {self.expected}")
        x = block.data
        lo, hi = float(x.min()), float(x.max())
        if lo < -1.0 or hi > self.params["adc_range"]:
            raise InputRejected("implausible", f"detector level {lo:g} .. {hi:g} outside -1 .. "
                                f"{self.params['adc_range']:g}")
        return x.astype(float).reshape(x.shape[0], -1, 2)

    def _start(self, x0: np.ndarray) -> None:
        """States from the first samples: who is received now, and the body between."""
        on = self.params["threshold_on"]
        self.up[:] = x0 > on
        self.present[:] = self.up
        heads = [k for k in range(len(self.blocks)) if self.present[k, 0]]
        tails = [k for k in range(len(self.blocks)) if self.present[k, 1]]
        for k in range(len(self.blocks)):
            body = any(min(h, t) < k < max(h, t) for h in heads for t in tails)
            if self.present[k].any() or body:
                self.stored[k] = 1
        self._started = True
        self._update_states()

    def decode(self, block: RawBlock):
        x = self._check(block)
        p = self.params
        fs = block.sample_rate
        self._fs = fs
        dt = 1.0 / fs
        t0 = block.t0
        n = x.shape[0]
        out = []
        if not self._started:
            self._start(x[0])
            self._prev = x[0]
        if self._last_report is None:
            out.append(self.occupancy(t0))
            self._reported = tuple(self.block_states)
            self._last_report = t0
        on, off = p["threshold_on"], p["threshold_off"]
        appear = max(p["confirm_time"], p["burst_window"])   # delay before an appearance is taken
        # fast path: no hysteresis edge and no pending confirmation in the block
        mn, mx = x.min(axis=0), x.max(axis=0)
        steady = bool(np.all(np.where(self.up, mn >= off, mx <= on)) and np.all(self.up == self.present))
        if not steady:
            prev = self._prev
            for i in range(n):
                t = t0 + i * dt
                xi = x[i]
                rise = ~self.up & (xi > on)
                fall = self.up & (xi < off)
                if rise.any() or fall.any():
                    for k, c in zip(*np.nonzero(rise | fall)):
                        thr = on if rise[k, c] else off
                        a, b = float(prev[k, c]), float(xi[k, c])
                        frac = (thr - a) / (b - a) if b != a else 1.0
                        self.edge[k, c] = t - dt + min(max(frac, 0.0), 1.0) * dt
                        if fall[k, c]:
                            self.lost[k, c] = self.edge[k, c]
                    self.up ^= rise | fall
                pending = (self.up != self.present) & (t - self.edge >= np.where(self.up, appear, p["confirm_time"])
                                                       - 1e-9)
                if pending.any():
                    for k, c in zip(*np.nonzero(pending)):
                        out.extend(self._confirmed(int(k), int(c), t))
                    self._update_states()
                    if tuple(self.block_states) != self._reported:
                        out.append(self.occupancy(t))
                        self._reported = tuple(self.block_states)
                        self._last_report = t
                prev = xi
        self._prev = x[-1]
        t_last = t0 + (n - 1) * dt
        if t_last - self._last_report >= p["report_period"] - 1e-9:
            out.append(self.occupancy(t_last))
            self._last_report = t_last
        return out

    def _update_states(self) -> None:
        for k in range(len(self.blocks)):
            if self.burst[k]:
                self.block_states[k] = OCCUPIED
            elif self.present[k, 0]:
                self.block_states[k] = CHECKED_IN
            elif self.present[k, 1]:
                self.block_states[k] = CHECKED_OUT
            elif self.stored[k] > 0:
                self.block_states[k] = OCCUPIED
            else:
                self.block_states[k] = CLEAR

    def _confirmed(self, k: int, c: int, t: float) -> list:
        """Carrier c of block k confirmed appearing or disappearing at t (onset self.edge[k, c])."""
        appeared = bool(self.up[k, c])
        self.present[k, c] = appeared
        other = 1 - c
        if self.burst[k]:
            if not self.present[k].any() and not self.up[k].any():
                self.burst[k] = False
            return []
        if appeared and self.up[k, other] and not self.present[k, other] \
                and abs(self.edge[k, other] - self.edge[k, c]) <= self.params["burst_window"]:
            # both carriers at once: interference (an appearance is taken burst_window after its
            # onset at the earliest, so neither edge was taken yet)
            self.burst[k] = True
            self.stats["noise_bursts"] += 1
            self.present[k, other] = True
            return []
        if c == 0 and appeared:
            return self._checked_in(k)
        if c == 1 and appeared and self.stored[k] == 0:
            self.stored[k] = 1
            self.stats["checkout_without_checkin"] += 1
        if c == 1 and not appeared and self.stored[k] > 0:
            ahead = self._ahead(k)
            if ahead < 0:
                self._checked_out(k)        # the tail leaves the equipped area
            elif self.up[ahead, 1]:
                self._checked_out(k)
                self.stats["integrity_confirmed"] += 1
            else:
                self.leaving[k] = float(self.edge[k, 1])   # released once the block ahead receives it
        if c == 1 and appeared:
            behind = self._ahead(k, -1)
            if behind >= 0 and abs(self.leaving[behind] - self.edge[k, 1]) <= self.params["handover_time"] \
                    and self.stored[behind] > 0:
                self._checked_out(behind)
                self.stats["integrity_confirmed"] += 1
        return []

    def _ahead(self, k: int, sign: int = 1) -> int:
        """The neighbour of block k in the running direction (``sign`` -1: behind), or -1."""
        return self.blocks[k]["above"] if sign * self.orient > 0 else self.blocks[k]["below"]

    def _checked_out(self, k: int) -> None:
        self.stored[k] -= 1
        self.checkouts[k] += 1
        self.stats["checkouts"] += 1
        self.leaving[k] = -math.inf

    def _checked_in(self, k: int) -> list:
        """The front's carrier appeared in block k: a check-in; a hand-over gives a fix."""
        self.stored[k] += 1
        self.checkins[k] += 1
        self.stats["checkins"] += 1
        b = self.blocks[k]
        t_on = float(self.edge[k, 0])
        window = self.params["handover_time"]
        sides = [(nb, d) for nb, d in ((b["below"], 1), (b["above"], -1)) if nb >= 0]
        # the neighbour that lost the front's carrier about now; else the one still receiving it
        # (a slow train; a second train's front farther on is received too, but not lost now)
        behind = [(nb, d) for nb, d in sides if abs(self.lost[nb, 0] - t_on) <= window] \
            or [(nb, d) for nb, d in sides if self.up[nb, 0]]
        if len(behind) != 1:
            return []
        nb, d = behind[0]
        self._check_missing(k, d)
        if d != self.orient:
            return []     # the front antenna trails: a reversing train, no front fix
        p = self.params
        boundary = b["start"] if d > 0 else b["end"]
        timing = p["max_speed"] / self._fs / math.sqrt(12.0)
        sigma = fix_sigma(p, timing)
        self.stats["fixes"] += 1
        lower, upper = (self.blocks[nb]["id"], b["id"]) if d > 0 else (b["id"], self.blocks[nb]["id"])
        ref = f"{lower}{SEPARATOR}{upper}"
        front = boundary + d * front_reach(p)
        return [PositionFix(t_on, self.sensor, self.unit_id, self.track.track_id, ref,
                            float(front), float(sigma), int(d))]

    def _check_missing(self, k: int, d: int) -> None:
        """Blocks behind the check-in into block k (direction d) that still hold a check-in
        farther behind than the longest train: their check-out was missed."""
        b = self.blocks[k]
        entry = b["start"] if d > 0 else b["end"]
        for j, bj in enumerate(self.blocks):
            exit_ = bj["end"] if d > 0 else bj["start"]
            if d * (entry - exit_) > self.params["max_train_length"] and self.stored[j] > 0 \
                    and not self.present[j].any() and not self._missing[j]:
                self._missing[j] = True
                self.stats["checkout_missing"] += 1
                self.missing_checkout.append(bj["id"])


def fix_bias_sigma(params: dict) -> float:
    """1-sigma [m] of the persistent part of a boundary fix: the boundary's installation error
    and the receiver's gain error, which moves the point where its level reaches threshold_on
    (slope of the coupling there)."""
    h, thr = params["antenna_height"], params["threshold_on"]
    u = onset_depth(thr, h)
    slope = 1.0 / (math.pi * h * (1.0 + (u / h) ** 2))
    return math.hypot(params["boundary_sigma"], params["adjust_sigma"] * thr / slope)


def depth_sigma(params: dict) -> float:
    """1-sigma [m] of the onset depth from the antenna height's variation (depth ~ h)."""
    return abs(onset_depth(params["threshold_on"], 1.0)) * params["height_sigma"]


SEPARATOR = "/"        # between the two block ids of a boundary fix's reference (lower/upper chainage)


def fix_sigma(params: dict, timing: float = 0.0) -> float:
    """1-sigma [m] of a boundary fix: root sum of squares of ``fix_bias_sigma``, ``depth_sigma``,
    ``offset_sigma`` and the onset timing ``timing`` [m] (the decoder's), at least MIN_FIX_SIGMA;
    with timing 0 the least a fix reports (the error model's floor)."""
    return max(math.sqrt(fix_bias_sigma(params) ** 2 + depth_sigma(params) ** 2 + params["offset_sigma"] ** 2
                         + timing ** 2), MIN_FIX_SIGMA)


def front_reach(params: dict) -> float:
    """Distance [m] of a boundary fix beyond its boundary in the running direction: the onset
    depth at ``threshold_on`` + ``front_antenna_offset``."""
    return onset_depth(params["threshold_on"], params["antenna_height"]) + params["front_antenna_offset"]


def error_model(params: dict, track, vehicle) -> ErrorModel:
    """Boundary fixes for the fusion: a boundary's installation error and a receiver's gain error
    move its detection point, the same for every passage of that boundary and independent between boundaries (a fix bias
    drawn anew per reference, included in the reported stddev); fault mode: a miscount (a
    check-in that is no train's front, e.g. interference longer than the burst window). Floor:
    ``fix_sigma`` without timing. References: the device's blocks (``block_table``, as the
    decoder), a fix naming the two blocks of its boundary ("lower/upper"): block window
    [start, end] + o x ``front_reach``, o the decoder's orientation (it gives no fix against it);
    an empty table if the track has no blocks of the device."""
    bias = fix_bias_sigma(params)
    references = None
    if track is not None:
        try:
            blocks = block_table(track, params)
        except TrackError:
            blocks = []    # the decoder refuses to run on it: no fix is honest
        shift = (int(params["orientation"]) or 1) * front_reach(params)
        references = ReferenceTable({str(b["id"]): ReferenceWindow(b["start"] + shift, b["end"] + shift)
                                     for b in blocks}, separator=SEPARATOR)
    return ErrorModel(SENSOR, "position", fix_bias_sigma=bias, fix_bias_per_reference=True,
                      reported_fix_bias=bias, faults=("miscount",), min_stddev=fix_sigma(params),
                      references=references)


SPEC = SensorSpec(
    node="checkin_loop", sensor=SENSOR, simulator=CheckinSimulator, decoder=CheckinDecoder,
    params=PARAMS, description="wayside HF check-in / check-out block detection (HSST, Kobe Port Island line): "
                               "block occupancy from the front's check-in to the rear's check-out, train-front "
                               "fixes at the block boundaries",
    seeds=("000", "002"), outputs=("position", "sections"), error_model=error_model,
)
