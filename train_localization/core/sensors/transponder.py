"""Transponder tag reader (on-board, UTM-02 urban maglev), seed 002 section 2.1.2.

Seed 002 section 2.1.2: UTM-02 initialises the train position and corrects the error of the
Doppler odometry with D-GPS and transponders; the transponder tags are installed on the
track about every 100 m, and the transponder reader on the train recognises the tag's
information. The seed gives nothing about the tag or the reader: the physics below is that
of a passive inductively coupled transponder, with assumed values marked as such.

Physics. The reader antenna, a loop of radius a (``antenna_radius``) under the vehicle, is
h (``reading_height``) above the tag on the guideway. Its field at the tag, the along-track
offset u folded into the distance as on the loop's axis (assumption: a and h alike), is

    k(u) = ((a^2 + h^2) / (a^2 + h^2 + u^2))^(3/2)        (1 at u = 0)

The passive tag draws its power from that field: it is powered while g k(u) >=
``activation_level`` (g: the coupling of the passage, 1-sigma ``coupling_sigma``: air gap
of the levitation, tag orientation), i.e. within the reading window

    |u| <= u_w = sqrt((a^2 + h^2) ((g / activation_level)^(2/3) - 1))

(0.71 m long with the defaults). Powered, it needs ``boot_time`` to start, then sends its id
again and again, a telegram of ``telegram_bits`` at ``bit_rate`` (T = bits / rate), each copy
corrupt with ``telegram_error_rate``; the reader takes the id after ``copies`` identical
good copies in a row. A read thus needs boot_time + copies x T inside the window: the
reader's speed limit is 2 u_w / (boot_time + copies T), about 140 km/h with the defaults
(UTM-02 runs at up to about 110 km/h: an assumption, not in seed 002). The tag answers by
load modulation, which the reader sees through the same coupling: the received level is
``amplitude`` x (g k)^2 while the tag answers (after its boot, until it leaves the window)
and noise only otherwise -- unlike a Eurobalise, which radiates its own up-link field
(core/sensors/eurobalise.py).

Raw signal (default 2 kHz: the window lasts 18 ms at 140 km/h, 36 samples): ``level`` [V]
the envelope of the tag's answer, ``tag_id`` [1] the tag code at the sample where the reader
accepted the id, 0 elsewhere. A tag's real position differs from its chainage in the track
file by its installation error, 1-sigma ``install_sigma`` (drawn once per tag, within
+-``INSTALL_BOUND`` sigma: a tag laid beyond is re-laid).

Decoder (the same for simulated, recorded and ingested blocks): an answer is a run of
samples above ``detect_level``; it began ``boot_time`` after the antenna entered the
window and ended when it left it, so the antenna was over the tag at
t_c = (t_on - boot_time + t_off) / 2 (the window is symmetric; each edge taken midway through the
sample interval in which the level stepped); the
window's nominal length over its duration gives the speed. Under an acceleration a the
antenna is over the tag at t_c only within a D^2 / 8 (D: the answer's duration,
``max_acceleration``); where that exceeds the window's half length (a stop or a reversal
over the tag) the read is stamped when the answer ended, the antenna then at the window's
edge (1-sigma: the half length). A run with a tag code -> the tag
(track file) -> PositionFix of the train front = tag chainage + ``antenna_offset`` at t_c,
1-sigma the root sum of squares of ``install_sigma``, the edge timing x speed and the
acceleration term; a tag gives no direction (0). An
answer without a code is a failed read (``stats["failed_reads"]``: too fast for two
copies, corrupt copies); a tag passed too fast to boot gives no answer at all. A read whose
tag cannot be reached from the previous read at ``max_speed`` is withheld
(``stats["implausible"]``). A code not in the track -> InputRejected("unknown_id"); a
negative level, one at the ``adc_range`` or a code that is no code -> "implausible".

Track equipment (kind ``transponder_tag``)::

    transponder_tag:
      - {id: T001, position: 100.0}                    # code: hashed from the id (1..2^20)
      - {id: T002, position: 200.0, code: 4711}        # or given
      - {every: 100.0, start: 50.0, end: 5950.0, id: "TG{n:03d}"}
"""
from __future__ import annotations

import hashlib
import math

import numpy as np

from ..measurements import PositionFix
from ..signals import InputRejected, RawBlock
from ..track import nearby_runs
from .base import MIN_FIX_SIGMA, Decoder, ErrorModel, Param, ReferenceTable, ReferenceWindow, SensorSpec, Simulator

KIND = "transponder_tag"
SENSOR = "transponder"
CODE_MAX = 2 ** 20          # tag codes 1..2^20 (exact in float32); 0 = no id
INSTALL_BOUND = 3.0         # a tag laid beyond 3 install_sigma is re-laid
SEED_SPACING = 100.0        # [m] seed 002 section 2.1.2: tags about every 100 m

PARAMS = {
    "antenna_offset": Param(3.0, "reader antenna distance behind the train front [m] (assumption: under the "
                                 "leading bogie); within a train of up to 1 km", (0.0, 1000.0)),
    "antenna_radius": Param(0.2, "radius a of the reader's loop antenna [m] (assumption)", (0.01, 2.0)),
    "reading_height": Param(0.25, "height h of the reader antenna above the tag [m] (assumption: under the "
                                  "chassis of a levitated vehicle)", (0.01, 2.0)),
    "activation_level": Param(0.3, "field, fraction of the one at u = 0, that powers the tag [1] (assumption: "
                                   "the reader's field margin over the tag's threshold)", (0.01, 0.99)),
    "coupling_sigma": Param(0.05, "1-sigma relative coupling of a passage [1] (levitation gap, tag "
                                  "orientation; assumption)", (0.0, 0.5)),
    "boot_time": Param(0.002, "time from power-up to the tag's first answer [s] (assumption)", (0.0, 1.0)),
    "telegram_bits": Param(64, "tag telegram length [bit] (assumption: 64-bit read-only transponder)", (8, 4096)),
    "bit_rate": Param(8000.0, "tag answer bit rate [bit/s] (assumption)", (100.0, 1.0e6)),
    "copies": Param(2, "identical good copies the reader needs to accept an id [1] (assumption)", (1, 10)),
    "telegram_error_rate": Param(1e-3, "probability that a telegram copy is corrupt [1] (assumption)", (0.0, 1.0)),
    "amplitude": Param(1.0, "received level of the tag's answer at u = 0 and nominal coupling [V]", (1.0e-3, 10.0)),
    "noise": Param(0.005, "1-sigma white noise of the level [V] (assumption)", (0.0, 1.0)),
    "install_sigma": Param(0.05, "1-sigma installation error of a tag's position vs its chainage in the track "
                                 "file [m] (assumption: bolted to the guideway, surveyed to +-0.15 m = 3 sigma)",
                           (0.0, 10.0)),
    "adc_range": Param(2.0, "level output range [V]; a level at or beyond it is implausible", (0.1, 100.0)),
    "detect_level": Param(0.03, "decoder: level above which the tag answers [V] (6 sigma of the noise, a "
                                "third of the level at the window's edge)", (1.0e-4, 10.0)),
    "max_acceleration": Param(1.5, "decoder: largest |acceleration| of the train [m/s^2] (assumption: above "
                                   "the emergency braking of an urban maglev): bounds how far from the tag the "
                                   "antenna is midway through a slow passage", (0.1, 10.0)),
    "max_speed": Param(42.0, "decoder: highest train speed between two reads [m/s] (assumption: 150 km/h, "
                             "above UTM-02's ~110 km/h)", (1.0, 200.0)),
}


def tag_codes(items: list[dict]) -> dict[str, int]:
    """Code (1..2^20, exact in float32) of each tag id: ``code`` key if given, else the id if
    it is such an integer, else a SHA-256 hash of the id with linear probing to a free value
    (in track order): the simulator and the decoder agree given the same track file."""
    out: dict[str, int] = {}
    used: set[int] = set()
    pending = []
    for it in items:
        tid = str(it["id"])
        if "code" in it or (tid.isdigit() and 1 <= int(tid) <= CODE_MAX):
            code = int(it.get("code", tid))
            if not 1 <= code <= CODE_MAX or code in used:
                raise ValueError(f"transponder tag {tid}: code {code} not in 1..{CODE_MAX} or used twice")
            out[tid] = code
            used.add(code)
        else:
            pending.append(tid)
    for tid in pending:
        code = int.from_bytes(hashlib.sha256(tid.encode()).digest()[:4], "big") % CODE_MAX + 1
        while code in used:
            code = code % CODE_MAX + 1
        out[tid] = code
        used.add(code)
    return out


def window_half_length(params: dict, gain: float = 1.0) -> float:
    """u_w [m]: half the reading window, where gain x k(u) falls to ``activation_level`` (0 if
    the tag is never powered)."""
    ratio = gain / params["activation_level"]
    if ratio <= 1.0:
        return 0.0
    d2 = params["antenna_radius"] ** 2 + params["reading_height"] ** 2
    return math.sqrt(d2 * (ratio ** (2.0 / 3.0) - 1.0))


def read_time(params: dict) -> float:
    """Time a read needs in the window [s]: boot + copies x telegram."""
    return params["boot_time"] + params["copies"] * params["telegram_bits"] / params["bit_rate"]


def speed_limit(params: dict, gain: float = 1.0) -> float:
    """Highest speed [m/s] at which a tag is read (every copy good): 2 u_w / read time."""
    return 2.0 * window_half_length(params, gain) / read_time(params)


def coupling(params: dict, u) -> np.ndarray:
    """k(u): the reader's field at the tag relative to u = 0."""
    d2 = params["antenna_radius"] ** 2 + params["reading_height"] ** 2
    return (d2 / (d2 + np.square(np.asarray(u, dtype=float)))) ** 1.5


class TransponderSimulator(Simulator):
    sensor = SENSOR
    channels = ("level", "tag_id")
    units = ("V", "1")
    default_sample_rate = 2000.0
    adc_lsb = {"V": 2.0 / 4096}   # 12-bit level over 2 V; the code exact

    def __init__(self, *args):
        super().__init__(*args)
        p = self.params
        items = self.track.items(KIND)
        codes = tag_codes(items)
        self._code = np.array([codes[str(it["id"])] for it in items], dtype=float)
        err = self.rng.normal(0.0, 1.0, len(items))
        while np.any(np.abs(err) > INSTALL_BOUND):
            bad = np.abs(err) > INSTALL_BOUND
            err[bad] = self.rng.normal(0.0, 1.0, int(bad.sum()))
        self._pos = np.array([float(it["position"]) for it in items]) + p["install_sigma"] * err
        order = np.argsort(self._pos)
        self._pos, self._code = self._pos[order], self._code[order]
        self._t_tel = p["telegram_bits"] / p["bit_rate"]
        self._reach = window_half_length(p, 1.0 + 5.0 * p["coupling_sigma"]) + 0.5
        self._passage: dict | None = None

    def _new_passage(self, k: int) -> dict:
        gain = max(1.0 + self.rng.normal(0.0, self.params["coupling_sigma"]), 0.0)
        return {"k": k, "gain": gain, "half": window_half_length(self.params, gain), "t_in": None,
                "copies": 0, "sent": 0, "done": False, "prev": None}

    def _answer(self, ps: dict, t: np.ndarray, inside: np.ndarray, tag: np.ndarray, off: int) -> np.ndarray:
        """Whether the tag answers at each sample of a run near it; writes the accepted code."""
        p = self.params
        answering = np.zeros(len(t), dtype=bool)
        prev_inside = ps["prev"]
        for i in range(len(t)):
            if inside[i] and not prev_inside:      # powered up (again: a reversal over the tag)
                ps.update(t_in=float(t[i]), copies=0, sent=0, done=False)
            if not inside[i]:
                ps["t_in"] = None
            prev_inside = bool(inside[i])
            if ps["t_in"] is None:
                continue
            since = float(t[i]) - ps["t_in"] - p["boot_time"]
            if since < 0.0:
                continue
            answering[i] = True
            # copies completed by now, each judged once
            while not ps["done"] and (ps["sent"] + 1) * self._t_tel <= since + 1e-12:
                ps["sent"] += 1
                if self.rng.random() < p["telegram_error_rate"]:
                    ps["copies"] = 0
                else:
                    ps["copies"] += 1
                if ps["copies"] >= p["copies"]:
                    ps["done"] = True
                    tag[off + i] = self._code[ps["k"]]
        ps["prev"] = prev_inside
        return answering

    def samples(self, times, position, speed, acceleration):
        p = self.params
        n = len(times)
        level = np.zeros(n)
        tag = np.zeros(n)
        if self._pos.size:
            u, runs = nearby_runs(self._pos, position - p["antenna_offset"], self._reach)
            for r0, r1, kk in runs:
                if kk < 0:
                    self._passage = None
                    continue
                ps = self._passage
                if ps is None or ps["k"] != kk or r0 != 0:
                    ps = self._new_passage(kk)
                self._passage = ps
                g = ps["gain"] * coupling(p, u[r0:r1])
                inside = g >= p["activation_level"]
                on = self._answer(ps, times[r0:r1], inside, tag, r0)
                level[r0:r1] = np.where(on, p["amplitude"] * g * g, 0.0)
        level = np.abs(level + self.rng.normal(0.0, p["noise"], n))
        return np.column_stack([np.minimum(level, p["adc_range"] * 0.999), tag])


class TransponderDecoder(Decoder):
    sensor = SENSOR
    channels = TransponderSimulator.channels

    def __init__(self, params, track):
        super().__init__(params, track)
        p = self.params
        items = track.items(KIND)
        codes = tag_codes(items)
        self._by_code = {codes[str(it["id"])]: it for it in items}
        self._window = 2.0 * window_half_length(p)
        # the window of the strongest passage (coupling + 3 sigma): where the antenna may be while
        # the tag answers
        self._half_max = window_half_length(p, 1.0 + 3.0 * p["coupling_sigma"])
        self._run: dict | None = None       # the answer under way: its start [s] and the codes in it
        self._last: tuple[float, float] | None = None   # (time, chainage) of the last published read
        self.stats = {key: 0 for key in ("answers", "reads", "failed_reads", "implausible")}

    def _check(self, block: RawBlock):
        p = self.params
        if block.channels != self.channels:
            raise InputRejected("channels", f"transponder channels {block.channels}, expected {self.channels}")
        level = block.data[:, 0].astype(float)
        tag = block.data[:, 1].astype(float)
        if float(level.min()) < -1e-6 or float(level.max()) >= p["adc_range"]:
            raise InputRejected("implausible", f"level {level.min():.3g}..{level.max():.3g} V outside "
                                               f"0..{p['adc_range']} V")
        codes = tag[tag != 0.0]
        if codes.size:
            if np.any((codes < 1) | (codes > CODE_MAX) | (codes != np.round(codes))):
                raise InputRejected("implausible", "tag_id channel holds a value that is no tag code")
            unknown = set(codes.astype(int).tolist()) - set(self._by_code)
            if unknown:
                raise InputRejected("unknown_id", f"tag code(s) {sorted(unknown)} not on track {self.track.track_id}")
        return level, tag

    def decode(self, block: RawBlock):
        p = self.params
        level, tag = self._check(block)     # raises before any state changes
        above = level > p["detect_level"]
        if self._run is None and not above.any():
            return []                        # the usual block: no tag answering
        dt = 1.0 / block.sample_rate
        # the level steps at the answer's start and end: each lies in the sample interval before
        # the first sample of the new state, at its middle (uniform: 1-sigma dt / sqrt(12))
        t = block.t0 + self.sample_offsets(block.n_samples, block.sample_rate) - 0.5 * dt
        out: list[PositionFix] = []
        change = np.flatnonzero(above[1:] != above[:-1]) + 1
        bounds = [0, *change.tolist(), block.n_samples]
        for a, b in zip(bounds[:-1], bounds[1:]):
            if above[a]:
                if self._run is None:
                    self._run = {"t_on": float(t[a]), "codes": set()}
                self._run["codes"].update(tag[a:b][tag[a:b] != 0.0].astype(int).tolist())
            elif self._run is not None:
                fix = self._close(float(t[a]), dt)
                if fix is not None:
                    out.append(fix)
        return out

    def _close(self, t_off: float, dt: float) -> PositionFix | None:
        p = self.params
        run, self._run = self._run, None
        self.stats["answers"] += 1
        if len(run["codes"]) != 1:          # no id accepted (too fast, corrupt copies) or two tags' ids
            self.stats["failed_reads"] += 1
            return None
        item = self._by_code[run["codes"].pop()]
        self.stats["reads"] += 1
        t_in = run["t_on"] - p["boot_time"]
        duration = max(t_off - t_in, dt)
        # at constant speed the antenna is over the tag midway through the window; an acceleration
        # a moves that point by up to a D^2 / 8. Beyond the window's half length (a stop, a
        # reversal over the tag) the read only says the antenna was in the window as it left it
        motion = p["max_acceleration"] * duration * duration / 8.0
        if motion < self._half_max:
            stamp = 0.5 * (t_in + t_off)
            speed = self._window / duration
            timing = speed * dt / math.sqrt(24.0)    # mean of two edges, each dt / sqrt(12)
        else:
            stamp, motion, timing = t_off, self._half_max, 0.0
        chainage = float(item["position"])
        if self._last is not None:
            t_last, s_last = self._last
            margin = 2.0 * INSTALL_BOUND * p["install_sigma"] + 2.0 * self._half_max
            if abs(chainage - s_last) > p["max_speed"] * abs(stamp - t_last) + margin:
                self.stats["implausible"] += 1
                return None
        self._last = (stamp, chainage)
        return PositionFix(float(stamp), self.sensor, self.unit_id, self.track.track_id, str(item["id"]),
                           fix_position(p, item), fix_sigma(p, timing, motion), 0)


def fix_sigma(params: dict, timing: float = 0.0, motion: float = 0.0) -> float:
    """1-sigma [m] of a tag fix: root sum of squares of ``install_sigma``, the edge timing
    ``timing`` [m] and the acceleration term ``motion`` [m] (the decoder's), at least MIN_FIX_SIGMA;
    with both 0 the least a fix reports (the error model's floor)."""
    return max(math.sqrt(params["install_sigma"] ** 2 + timing ** 2 + motion ** 2), MIN_FIX_SIGMA)


def fix_position(params: dict, item: dict) -> float:
    """Train-front chainage [m] of a fix of tag ``item``: its chainage + ``antenna_offset`` (the
    decoder assumes the antenna behind the front towards decreasing chainage, as the simulator)."""
    return float(item["position"]) + params["antenna_offset"]


def error_model(params: dict, track, vehicle) -> ErrorModel:
    """Tag fixes for the fusion: white (each tag's installation error is its own, read once a
    passage; the edge timing), both in the decoder's stddev; fault modes: a misread id, an offset of a run of fixes.
    Floor:
    ``fix_sigma`` without timing, max(install_sigma, 1 mm). References: every tag of the track,
    window the point chainage + antenna_offset (``fix_position``)."""
    references = None
    if track is not None:
        references = ReferenceTable({str(it["id"]): ReferenceWindow(fix_position(params, it), fix_position(params, it))
                                     for it in track.items(KIND)})
    return ErrorModel(SENSOR, "position", faults=("misread", "offset"), min_stddev=fix_sigma(params),
                      references=references)


SPEC = SensorSpec(
    node="tag_reader", sensor=SENSOR, simulator=TransponderSimulator, decoder=TransponderDecoder,
    params=PARAMS, description="on-board transponder tag reader (UTM-02): passive tags about every 100 m -> "
                               "position fix", seeds=("002",), outputs=("position",), error_model=error_model,
)
