"""Eurobalise reader (on-board BTM + antenna over wayside balises), seed 001.

Physics (seed 001, "magnetic intensity from wayside transmitter to on-board
transmitter about the train speed in ATP system"):

  * a telegram of l_t bits sent at r_t bit/s takes T_r = l_t / r_t          (eq. 1)
    (standard long telegram 1023 bit at 564 kbit/s: 1.8138 ms, Table 1);
  * at train speed V_s the antenna must stay in contact over D_t = T_r V_s  (eq. 2)
    (50.38 mm at 100 km/h ... 302.3 mm at 600 km/h);
  * the reading horizontal distance is x = D_t / 2 - a / 2: half the transmission
    distance either side of the balise centre, less half the 40 mm coil (Table 2);
  * field of the balise's rectangular a x b loop (N_w turns, current I_w) at
    horizontal offset x and height y                                        (eq. 3)
  * self inductances (eq. 4), mutual inductance M = mu0 H(I_w) N_n c d / I_w (eq. 5),
    emf induced in the tuned antenna circuit (eq. 6) and the read field strength
    H_min that the antenna has to detect at speed V_s (eq. 7; Tables 3 and 4).

The pure functions below reproduce Tables 2-4 from Table 1 (``TABLE1``). Note that
eq. 7 inverts eq. 6, so H_min(V_s) equals the eq. 3 field at the reading distance
x(V_s): a BTM of sensitivity H_th reads a telegram at speed V_s iff
H(x(V_s)) >= H_th, i.e. iff the readable window -- the antenna centre within
a/2 + x_H of the balise centre, H(x_H) = H_th -- is at least D_t long.

Simulation. The antenna (``antenna_offset`` behind the train front) passes the
balises of the track (equipment kind ``eurobalise``). Raw signal (default 5 kHz):

  * ``field_strength`` [A/m]: magnitude of the up-link field at the antenna, eq. 3
    with x = antenna-centre offset from the balise centre and y = ``vertical_distance``,
    times a per-passage gain (balise current tolerance, metal masses near the balise
    -- seed 001 ref. 2 --, antenna height) of 1-sigma ``field_sigma``, plus white
    receiver noise ``field_noise``;
  * ``telegram`` [1]: the 14-bit telegram id (NID) of the balise at the sample where
    a telegram has been received completely, 0 elsewhere. Each balise of the track sends
    the standard (long) telegram of 1023 bit or the short one of 341 bit (its ``telegram``
    key, ``long`` by default): seed 001 section 1, the long telegram is read up to
    300 km/h, above it (300-500 km/h) the short one is needed, and above 500 km/h no
    balise transmission is usable. These limits hold whatever the field: a copy completing
    above its telegram's TELEGRAM_MAX_SPEED is not received. A telegram copy completes
    T_r after the antenna entered the readable window (gain x H(max(|u| - a/2, 0)) >=
    ``read_threshold``) and counts only if the antenna is still inside the window
    then; copies are repeated every T_r while inside, each is corrupt with
    probability ``telegram_error_rate`` (CRC failure). The first good copy is
    delivered once per window; if none completes (window too short at high speed,
    all copies corrupt) the passage is a failed read.

  The balise's real centre differs from the chainage in the track file by a constant
  installation/survey error of 1-sigma ``location_sigma`` per balise (drawn once), within
  the location accuracy it is commissioned to (+-``LOCATION_BOUND`` sigma: ETCS gives the
  balise location accuracy as a bound, Q_LOCACC, and a balise surveyed beyond it is re-laid,
  so a draw beyond it is drawn again). Where the track gives the balise's Q_LOCACC (its
  ``q_locacc`` key or the national value of its ``etcs`` block, core/etcs/track_data.py) that
  bound is Q_LOCACC: the balise's 1-sigma is Q_LOCACC / LOCATION_BOUND, in the simulator and in
  the decoder's stddev alike (``balise_location_sigma``).

Sample rate: the field peak is 0.31 m wide at half maximum (eq. 3, y = 200 mm),
2.2 ms at 500 km/h: 5 kHz gives 11 samples across it; 2 channels -> 10 k samples/s.

Decoder: a passage is a run of samples with the field above ``detect_level`` (or half
the read threshold if lower; hysteresis 0.8x). The antenna was over the balise centre at the midpoint of the two
half-maximum crossings (linear interpolation); the crossings' distance in time and
the known half-maximum width of eq. 3 give |v|. The telegram id of the passage ->
balise (track file) -> PositionFix of the train front = balise chainage +
``antenna_offset``, stamped at the balise-centre time, stddev from the peak-time
estimate (noise / field slope, sampling) and ``location_sigma``. Direction: ETCS
reads it from the order of the balises of a group (entries with the same ``group``
key less than ``group_length`` apart read one after the other); a single balise
gives none (direction 0). A passage with field but no telegram is counted in
``stats["failed_reads"]``; an id not in the track -> InputRejected("unknown_id").

Track equipment (kind ``eurobalise``)::

    eurobalise:
      - {id: "101", position: 1200.0}                     # integer id 1..16383 = NID
      - {id: BG7a, position: 2500.0, group: BG7}          # names get a hashed NID,
      - {id: BG7b, position: 2503.0, group: BG7, nid: 4711}   # or give ``nid`` explicitly
      - {every: 1000.0, start: 500.0, end: 9500.0, id: "EB{n:03d}"}

The NID fits exactly in float32 (14 bits like ETCS NID_BG); 0 means "no telegram".
"""
from __future__ import annotations

import hashlib
import math

import numpy as np

from ..measurements import PositionFix
from ..signals import InputRejected, RawBlock
from ..etcs.track_data import q_locacc_of_balise
from ..track import TrackError, nearby_runs
from .base import MIN_FIX_SIGMA, Decoder, ErrorModel, Param, ReferenceTable, ReferenceWindow, SensorSpec, Simulator

KIND = "eurobalise"
MU0 = 4e-7 * math.pi           # permeability of free space [H/m]
KMH = 1.0 / 3.6                # km/h -> m/s
NID_MAX = 2 ** 14 - 1          # 14-bit telegram id (ETCS NID_BG); 0 = no telegram

# Seed 001 Table 1: ERTMS/ETCS on-board antenna and standard balise characteristics.
TABLE1 = {
    "bit_rate": 564e3,         # balise transmission rate [bit/s]
    "telegram_bits": 1023,     # standard (long) telegram length [bit]
    "c": 0.040,                # antenna coil width [m]
    "d": 0.040,                # antenna coil length [m]
    "R_n": 0.3,                # antenna internal resistance [ohm]
    "R_L": 50.0,               # antenna load resistance [ohm]
    "C": 1.474e-9,             # parasitic + tuning capacitance C_p + C_n [F]
    "L_n": 960e-9,             # antenna inductance [H]
    "N_n": 7,                  # antenna turns
    "a": 0.040,                # balise coil width [m]
    "b": 0.040,                # balise coil length [m]
    "N_w": 7,                  # balise turns
    "L_w": 960e-9,             # balise inductance [H]
    "I_w": 10e-3,              # balise current [A]
    "f": 4.23e6,               # balise transmission frequency [Hz]
    "y": 0.200,                # vertical antenna-balise distance [m]
}
# Telegram lengths [bit] (seed 001 section 1 and Table 1): the standard (long) telegram, read
# up to 300 km/h, and the short one that 300-500 km/h needs
TELEGRAM_BITS = {"long": 1023, "short": 341}
# Highest speed [m/s] at which each telegram is transmitted (seed 001 section 1: no standard
# telegram at 300-500 km/h, no balise transmission usable above 500 km/h), whatever the field
TELEGRAM_MAX_SPEED = {"long": 300.0 * KMH, "short": 500.0 * KMH}

PARAMS = {
    "antenna_offset": Param(2.0, "distance of the antenna centre behind the train front [m] "
                                 "(assumption: antenna under the leading bogie); within a train of up to 1 km",
                            (0.0, 1000.0)),
    "bit_rate": Param(564e3, "up-link bit rate r_t [bit/s] (seed 001 Table 1)", (1.0e5, 1.0e6)),
    "vertical_distance": Param(0.200, "vertical distance antenna-balise y [m] (seed 001 Table 1)", (0.05, 1.0)),
    "balise_current": Param(10e-3, "balise loop current I_w [A] (seed 001 Table 1)", (1.0e-4, 1.0)),
    "read_threshold": Param(1.78e-3, "BTM read sensitivity H_th [A/m]: seed 001 Table 4's 1.957 mA/m, the "
                                     "field that reads the long telegram at 300 km/h (sec. 1), with the margin "
                                     "of a passage 3 field_sigma weak (x 0.91): the window fits the long telegram "
                                     "to 300 km/h on such a passage (385 km/h on a nominal one) and the short one "
                                     "to 900 km/h; seed 001 sec. 1's limits stop them at 300 and 500 km/h",
                            (1.0e-5, 0.1)),
    "field_sigma": Param(0.03, "1-sigma per-passage relative variation of the up-link field [1] (balise "
                               "current tolerance, metal masses/rebar near the balise: seed 001 ref. 2, "
                               "antenna height; assumption)", (0.0, 1.0)),
    "field_noise": Param(20e-6, "1-sigma white noise of the field-strength channel [A/m] (envelope "
                                "detector/ADC incl. EMI, ~1 % of the peak; assumption, well above the "
                                "~1 uA/m thermal floor of R_L through eq. 6)", (0.0, 0.01)),
    "telegram_error_rate": Param(1e-3, "probability that one received telegram copy is corrupt (CRC) [1]: "
                                       "1023 bit x BER 1e-6 of the Eurobalise contact zone (SUBSET-036)",
                                 (0.0, 1.0)),
    "location_sigma": Param(0.33, "1-sigma error of a balise's real centre vs its chainage in the track "
                                  "file [m] (installation + survey; ETCS balise location accuracy +-1 m "
                                  "(SUBSET-036) taken as 3 sigma, the bound of the simulated error)", (0.0, 10.0)),
    "silent_balises": Param("", "comma-separated ids of balises of the track that are out of order: no up-link "
                                "field, no telegram (simulation only; a linked group missed, docs/etcs.md)"),
    "detect_level": Param(0.5e-3, "field above which the decoder considers a balise passage [A/m] "
                                  "(~25 sigma of field_noise, ~1/4 of the 2.18 mA/m peak)", (1.0e-6, 0.1)),
    "group_length": Param(12.0, "balises of one group (same 'group' key) read within this distance of "
                                "each other give the direction [m] (ETCS balise group extent; assumption)",
                          (1.0, 100.0)),
    "max_acceleration": Param(2.0, "largest magnitude of the acceleration of the train [m/s^2] for the "
                                   "plausibility of the distance between two balise reads (assumption: above the "
                                   "emergency braking "
                                   "of high-speed and maglev trains, ~1.2-1.5 m/s^2, and the profiles of the "
                                   "scenarios, <= 1.1 m/s^2)", (0.1, 10.0)),
    "speed_tolerance": Param(0.15, "relative error bound of the speed measured from the width of the field "
                                   "peak for that plausibility [1] (the width scales with the antenna height: "
                                   "+-20 mm of vertical_distance = 10 %; sampling of the peak < 4 %)", (0.0, 1.0)),
}


# ----------------------------------------------------------------------------------
# Seed 001 model as pure functions (SI units; defaults = Table 1)
# ----------------------------------------------------------------------------------

def telegram_time(bits: float = TABLE1["telegram_bits"], bit_rate: float = TABLE1["bit_rate"]) -> float:
    """T_r = l_t / r_t [s] (seed 001 eq. 1); 1023 bit / 564 kbit/s = 1.8138 ms."""
    return float(bits) / float(bit_rate)


def transmission_distance(speed, t_r: float | None = None):
    """D_t = T_r V_s [m] (seed 001 eq. 2) for speed [m/s] (sign ignored)."""
    t_r = telegram_time() if t_r is None else t_r
    return np.abs(np.asarray(speed, dtype=float)) * t_r


def reading_distance(speed, t_r: float | None = None, a: float = TABLE1["a"]):
    """Reading horizontal distance x = D_t / 2 - a / 2 [m] (seed 001 Table 2, Fig. 8).

    Half the transmission distance on either side of the balise centre, less half
    the 40 mm balise coil. Negative below ~60 km/h (the paper keeps the sign; eq. 3
    only uses x^2).
    """
    return transmission_distance(speed, t_r) / 2.0 - a / 2.0


def loop_field(x, y: float = TABLE1["y"], a: float = TABLE1["a"], b: float = TABLE1["b"],
               turns: float = TABLE1["N_w"], current: float = TABLE1["I_w"]):
    """Field strength H [A/m] of a rectangular a x b loop at horizontal offset x, height y
    (seed 001 eq. 3)::

        H = N a b I / (4 pi sqrt((a/2)^2 + (b/2)^2 + x^2 + y^2))
            * (1 / ((a/2)^2 + x^2 + y^2) + 1 / ((b/2)^2 + x^2 + y^2))
    """
    x2 = np.square(np.asarray(x, dtype=float))
    y2 = y * y
    ha2, hb2 = (a / 2.0) ** 2, (b / 2.0) ** 2
    return (turns * a * b * current / (4.0 * math.pi * np.sqrt(ha2 + hb2 + x2 + y2))
            * (1.0 / (ha2 + x2 + y2) + 1.0 / (hb2 + x2 + y2)))


def self_inductance(turns: float = TABLE1["N_w"], a: float = TABLE1["a"], b: float = TABLE1["b"],
                    current: float = TABLE1["I_w"], x: float = 0.0, y: float = 0.0) -> float:
    """L = N Phi / I = N mu0 H(I) a b / I [H] (seed 001 eq. 4, balise L_w; antenna L_n with
    N_n, c, d, I_n). H from eq. 3 in the loop's own plane (x = y = 0 by default). This
    flux estimate gives 2.2 uH for Table 1's coils; the eq. 6 / eq. 7 computations use
    Table 1's stated 960 nH, as the paper does."""
    h = float(loop_field(x, y, a, b, turns, current))
    return turns * MU0 * h * a * b / current


def mutual_inductance(x, y: float = TABLE1["y"], a: float = TABLE1["a"], b: float = TABLE1["b"],
                      turns_w: float = TABLE1["N_w"], current: float = TABLE1["I_w"],
                      c: float = TABLE1["c"], d: float = TABLE1["d"], turns_n: float = TABLE1["N_n"]):
    """M = mu0 H(I_w) N_n c d / I_w [H] (seed 001 eq. 5; Table 3 at the reading distance)."""
    return MU0 * loop_field(x, y, a, b, turns_w, current) * turns_n * c * d / current


def _circuit_factor(omega: float, l_n: float, r_n: float, r_l: float, cap: float) -> float:
    """sqrt((w L_n / R_L + w R_n C)^2 + (1 - w^2 L_n C + R_n / R_L)^2) of eq. 6 and 7."""
    return math.hypot(omega * l_n / r_l + omega * r_n * cap, 1.0 - omega * omega * l_n * cap + r_n / r_l)


def induced_emf(mutual, current: float = TABLE1["I_w"], f: float = TABLE1["f"],
                l_w: float = TABLE1["L_w"], l_n: float = TABLE1["L_n"], r_n: float = TABLE1["R_n"],
                r_l: float = TABLE1["R_L"], cap: float = TABLE1["C"]):
    """|u_n| [V] induced in the tuned antenna circuit (seed 001 eq. 6)::

        u_n = w k sqrt(L_w L_n) I_w / sqrt((w L_n/R_L + w R_n C)^2 + (1 - w^2 L_n C + R_n/R_L)^2)

    with the coupling factor k = M / sqrt(L_w L_n).
    """
    omega = 2.0 * math.pi * f
    k = np.asarray(mutual, dtype=float) / math.sqrt(l_w * l_n)
    return omega * k * math.sqrt(l_w * l_n) * current / _circuit_factor(omega, l_n, r_n, r_l, cap)


def read_field_strength(emf, f: float = TABLE1["f"], l_n: float = TABLE1["L_n"], r_n: float = TABLE1["R_n"],
                        r_l: float = TABLE1["R_L"], cap: float = TABLE1["C"], c: float = TABLE1["c"],
                        d: float = TABLE1["d"], turns_n: float = TABLE1["N_n"]):
    """Read field strength H_min [A/m] the antenna must detect (seed 001 eq. 7)::

        H_min = u_n sqrt(...) / (w mu0 c d N_n)
    """
    omega = 2.0 * math.pi * f
    return (np.asarray(emf, dtype=float) * _circuit_factor(omega, l_n, r_n, r_l, cap)
            / (omega * MU0 * c * d * turns_n))


def balise_telegram_bits(item: dict) -> int:
    """Length [bit] of the telegram a balise of the track sends: its ``telegram`` key, ``long``
    (the default, 1023 bit) or ``short`` (341 bit); TrackError otherwise."""
    kind = str(item.get("telegram", "long"))
    if kind not in TELEGRAM_BITS:
        raise TrackError(f"eurobalise {item.get('id')}: telegram {kind!r} is not one of {', '.join(TELEGRAM_BITS)}")
    return TELEGRAM_BITS[kind]


def required_field(speed, t_r: float | None = None, y: float = TABLE1["y"],
                   current: float = TABLE1["I_w"]):
    """H_min [A/m] needed to read a telegram at ``speed`` [m/s]: eq. 1-2 -> x (Table 2)
    -> M (eq. 5, Table 3) -> u_n (eq. 6) -> H_min (eq. 7, Table 4)."""
    x = reading_distance(speed, t_r)
    m = mutual_inductance(x, y, current=current)
    return read_field_strength(induced_emf(m, current=current))


def window_offset(threshold: float, y: float = TABLE1["y"], current: float = TABLE1["I_w"]) -> float:
    """x_H >= 0 [m] where the eq. 3 field falls to ``threshold`` [A/m]; -1 if the field
    never reaches it (bisection; H decreases monotonically in |x|)."""
    if threshold > float(loop_field(0.0, y, current=current)):
        return -1.0
    lo, hi = 0.0, 1.0
    while float(loop_field(hi, y, current=current)) > threshold:
        hi *= 2.0
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        if float(loop_field(mid, y, current=current)) > threshold:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def window_half_width(threshold: float, y: float = TABLE1["y"], current: float = TABLE1["I_w"],
                      a: float = TABLE1["a"]) -> float:
    """Half-length [m] of the readable window (antenna-centre offset from the balise centre):
    a/2 + x_H, the inverse of Table 2's x = D_t/2 - a/2; -1 if nothing is readable."""
    x_h = window_offset(threshold, y, current)
    return -1.0 if x_h < 0 else a / 2.0 + x_h


def max_read_speed(threshold: float, t_r: float | None = None, y: float = TABLE1["y"],
                   current: float = TABLE1["I_w"]) -> float:
    """Highest speed [m/s] at which a telegram of duration T_r fits in the readable window
    (D_t(V) = window length); 0 if nothing is readable."""
    t_r = telegram_time() if t_r is None else t_r
    half = window_half_width(threshold, y, current)
    return max(0.0, 2.0 * half / t_r)


def telegram_ids(items: list[dict]) -> dict[str, int]:
    """Telegram id (NID, 1..16383, exact in float32) of each balise id.

    ``nid`` key if given, else the id itself if it is an integer 1..16383, else a
    SHA-256 hash of the id with linear probing to a free value (in track order), so
    the simulator and the decoder agree given the same track file.
    """
    out: dict[str, int] = {}
    used: set[int] = set()
    pending = []
    for it in items:
        bid = str(it["id"])
        if "nid" in it:
            nid = int(it["nid"])
            if not 1 <= nid <= NID_MAX:
                raise ValueError(f"eurobalise {bid}: nid {nid} not in 1..{NID_MAX}")
        elif bid.isdigit() and 1 <= int(bid) <= NID_MAX:
            nid = int(bid)
        else:
            pending.append(bid)
            continue
        if nid in used:
            raise ValueError(f"eurobalise {bid}: telegram id {nid} used twice")
        out[bid] = nid
        used.add(nid)
    for bid in pending:
        if bid in out:
            continue
        nid = 1 + int.from_bytes(hashlib.sha256(bid.encode()).digest()[:4], "little") % NID_MAX
        while nid in used:
            nid = nid % NID_MAX + 1
        out[bid] = nid
        used.add(nid)
    return out


def _half_max_geometry(y: float) -> tuple[float, float]:
    """(half-width [m] of the eq. 3 field at half maximum, |dH/dx| there per unit peak [1/m])."""
    peak = float(loop_field(0.0, y))
    xh = window_offset(0.5 * peak, y)
    eps = 1e-5
    slope = abs(float(loop_field(xh + eps, y) - loop_field(xh - eps, y))) / (2 * eps) / peak
    return xh, slope


# ----------------------------------------------------------------------------------
# Simulator
# ----------------------------------------------------------------------------------

NEAR_RANGE = 1.5   # [m] beyond this the field of a balise is < 1e-3 of its peak (ignored)
PENDING_READS = 2  # withheld reads kept as references of the plausibility check
LOCATION_BOUND = 3.0  # location accuracy bound / location_sigma (the +-1 m of SUBSET-036 is 3 sigma)


class EurobaliseSimulator(Simulator):
    sensor = KIND
    channels = ("field_strength", "telegram")
    units = ("A/m", "1")
    adc_lsb = {"A/m": 2e-6}  # field channel 2 uA/m (1/10 of its noise); the telegram id stays exact
    default_sample_rate = 5000.0

    def __init__(self, *args):
        super().__init__(*args)
        p = self.params
        items = self.track.items(KIND)
        nid = telegram_ids(items)
        pos = np.array([it["position"] for it in items], dtype=float)
        pos = pos + self._installation_errors(np.array([balise_location_sigma(p, self.track, it) for it in items]))
        silent = {b.strip() for b in str(p["silent_balises"]).split(",") if b.strip()}
        unknown = silent - {str(it["id"]) for it in items}
        if unknown:
            raise TrackError(f"silent_balises names balises not on track {self.track.track_id}: "
                             f"{', '.join(sorted(unknown))}")
        order = np.array([k for k in np.argsort(pos, kind="stable") if str(items[k]["id"]) not in silent], dtype=int)
        self._pos = pos[order]
        self._nid = np.array([nid[str(items[i]["id"])] for i in order], dtype=float)
        # T_r of each balise's telegram [s]
        self._t_r = np.array([telegram_time(balise_telegram_bits(items[i]), p["bit_rate"]) for i in order])
        # highest speed each balise's telegram is received at [m/s] (seed 001 section 1)
        self._v_max = np.array([TELEGRAM_MAX_SPEED[str(items[i].get("telegram", "long"))] for i in order])
        self._passage: dict | None = None

    def _installation_errors(self, sigma: np.ndarray) -> np.ndarray:
        """Real centre minus track-file chainage of balises of 1-sigma ``sigma`` [m]: Gaussian
        within the commissioned accuracy bound (beyond it: re-laid, drawn again)."""
        err = self.rng.standard_normal(sigma.size) * sigma
        beyond = np.abs(err) > LOCATION_BOUND * sigma
        while beyond.any():
            err[beyond] = self.rng.standard_normal(int(beyond.sum())) * sigma[beyond]
            beyond = np.abs(err) > LOCATION_BOUND * sigma
        return err

    def _new_passage(self, k: int) -> dict:
        p = self.params
        gain = max(0.05, 1.0 + p["field_sigma"] * self.rng.normal())
        half = window_half_width(p["read_threshold"] / gain, p["vertical_distance"], p["balise_current"])
        return {"k": k, "gain": gain, "half": half, "prev": None, "t_in": None, "copy": 1, "done": False}

    def _copies(self, ps: dict, t_limit: float, t: np.ndarray, spd: np.ndarray, tel: np.ndarray, off: int) -> None:
        """Telegram copies completing up to t_limit while in the window; deliver the first good
        one received at a speed ``spd`` [m/s] (per sample of ``t``) within its telegram's limit."""
        err = self.params["telegram_error_rate"]
        while not ps["done"]:
            t_done = ps["t_in"] + ps["copy"] * self._t_r[ps["k"]]
            if t_done > t_limit + 1e-12:
                return
            ps["copy"] += 1
            if self.rng.random() < err:
                continue
            i = min(int(np.searchsorted(t, t_done - 1e-9)), len(t) - 1)
            if abs(spd[i]) > self._v_max[ps["k"]] * (1.0 + 1e-9):
                continue                   # too fast for this telegram (seed 001 section 1)
            tel[off + i] = self._nid[ps["k"]]
            ps["done"] = True

    def _telegrams(self, ps: dict, t: np.ndarray, au: np.ndarray, spd: np.ndarray, tel: np.ndarray,
                   off: int) -> None:
        half = ps["half"]
        inside = au <= half
        if ps["prev"] is None:
            ps["prev"] = (t[0], au[0], bool(inside[0]))
        pt, pa, pin = ps["prev"]
        tt, aa, ii = np.r_[pt, t], np.r_[pa, au], np.r_[pin, inside]
        for c in np.flatnonzero(ii[1:] != ii[:-1]) + 1:
            frac = (aa[c - 1] - half) / (aa[c - 1] - aa[c])
            t_cross = tt[c - 1] + frac * (tt[c] - tt[c - 1])
            if ii[c]:                      # entering the readable window
                ps.update(t_in=t_cross, copy=1, done=False)
            else:                          # leaving it: copies completed before count
                if ps["t_in"] is not None:
                    self._copies(ps, t_cross, t, spd, tel, off)
                ps["t_in"] = None
        if ps["t_in"] is not None:
            self._copies(ps, t[-1], t, spd, tel, off)
        ps["prev"] = (t[-1], au[-1], bool(inside[-1]))

    def samples(self, times, position, speed, acceleration):
        p = self.params
        n = len(times)
        tel = np.zeros(n)
        h = np.zeros(n)
        if self._pos.size:
            ant = position - p["antenna_offset"]
            u, runs = nearby_runs(self._pos, ant, NEAR_RANGE)
            spd = np.broadcast_to(np.asarray(speed, dtype=float), np.shape(times))
            gain = np.zeros(n)
            for r0, r1, kk in runs:
                if kk < 0:
                    self._passage = None
                    continue
                ps = self._passage
                if ps is None or ps["k"] != kk or r0 != 0:
                    ps = self._new_passage(kk)
                gain[r0:r1] = ps["gain"]
                self._telegrams(ps, times[r0:r1], np.abs(u[r0:r1]), spd[r0:r1], tel, r0)
                self._passage = ps
            h = gain * loop_field(u, p["vertical_distance"], current=p["balise_current"])
        field = np.abs(h + self.rng.normal(0.0, p["field_noise"], n))
        return np.column_stack([field, tel])


# ----------------------------------------------------------------------------------
# Decoder
# ----------------------------------------------------------------------------------

def _reach(u1: float, u2: float, dt: float, acc: float) -> tuple[float, float] | None:
    """(least, most) signed distance [m] covered in dt [s] from the signed speed u1 to u2
    [m/s] with |acceleration| <= acc: brake then accelerate / accelerate then brake at the
    bound (the speed may change sign on the way: a reversal). None if no such profile joins
    u1 and u2."""
    if abs(u2 - u1) > acc * dt * (1.0 + 1e-9) + 1e-9:
        return None
    t_up = min(max((u2 - u1 + acc * dt) / (2.0 * acc), 0.0), dt)     # the two ramps meet here
    t_down = dt - t_up
    v_top, v_low = u1 + acc * t_up, u1 - acc * t_down
    return (0.5 * (u1 + v_low) * t_down + 0.5 * (v_low + u2) * t_up,
            0.5 * (u1 + v_top) * t_up + 0.5 * (v_top + u2) * t_down)


def _joinable(step: float, speeds1: tuple, speeds2: tuple, dt: float, acc: float, margin: float) -> bool:
    """Whether signed speeds u1 in speeds1 = (lo, hi) and u2 in speeds2 can be joined in dt
    with |acceleration| <= acc covering the signed distance step (+-margin). Both bounds
    of _reach grow with u1 and u2: the extremes lie at the corners of the box of speeds,
    moved along its edges into the band |u2 - u1| <= acc dt where needed."""
    (lo1, hi1), (lo2, hi2) = speeds1, speeds2
    band = acc * dt
    if lo2 > hi1 + band or lo1 > hi2 + band:
        return False

    def corner(a, b):
        return (a, min(b, a + band)) if b > a + band else (min(a, b + band), b)
    least = _reach(*corner(lo1, lo2), dt, acc)[0]
    most = _reach(*corner(hi1, hi2), dt, acc)[1]
    return least - margin <= step <= most + margin


class EurobaliseDecoder(Decoder):
    sensor = KIND
    channels = EurobaliseSimulator.channels

    MAX_PASSAGE = 120.0   # [s] a longer passage (train standing over a balise) is dropped

    def __init__(self, params, track):
        super().__init__(params, track)
        p = self.params
        items = track.items(KIND)
        nid = telegram_ids(items)
        for it in items:
            balise_telegram_bits(it)   # a track that names no telegram length is refused here too
        self._by_nid = {nid[str(it["id"])]: it for it in items}
        self._half_width, self._rel_slope = _half_max_geometry(p["vertical_distance"])
        self._peak_nominal = float(loop_field(0.0, p["vertical_distance"], current=p["balise_current"]))
        self._active = False
        self._buf: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        self._buf_t0 = 0.0
        self._last_read: tuple[float, dict] | None = None
        # plausibility of a read: (time, balise, speed, direction of travel) of the last
        # published read and of the last withheld one
        self._anchor: tuple[float, dict, float, int] | None = None
        self._pending: list[tuple[float, dict, float, int]] = []
        self.stats = {"passages": 0, "reads": 0, "failed_reads": 0, "orphan_telegrams": 0,
                      "unknown_id": 0, "dropped_passages": 0, "implausible": 0}

    def decode(self, block: RawBlock):
        p = self.params
        f32 = block.channel("field_strength")
        tel32 = block.channel("telegram")
        f_min, f_max = float(f32.min()), float(f32.max())
        if f_min < -10 * p["field_noise"] or f_max > 20.0 * self._peak_nominal:
            raise InputRejected("implausible", f"field strength {f_min:.3g}..{f_max:.3g} A/m is outside "
                                               f"what a balise can produce")
        any_tel = np.count_nonzero(tel32) > 0
        if any_tel:
            tel = tel32.astype(float)
            if np.any((tel < 0) | (tel > NID_MAX) | (tel != np.round(tel))):
                raise InputRejected("implausible", "telegram channel holds a value that is no 14-bit id")
        on = min(p["detect_level"], 0.5 * p["read_threshold"])   # the readable window lies inside
        off = 0.8 * on
        if not (self._active or any_tel or f_max > on):
            return []   # the usual block: no balise near, no telegram
        f = f32.astype(float)
        if not any_tel:
            tel = tel32.astype(float)
        t = block.times()
        out: list[PositionFix] = []
        errors: list[InputRejected] = []
        i, n = 0, len(f)
        while i < n:
            if not self._active:
                above = np.flatnonzero(f[i:] > on)
                j = i + int(above[0]) if above.size else n
                self.stats["orphan_telegrams"] += int(np.count_nonzero(tel[i:j]))
                if j >= n:
                    break
                self._active, self._buf, self._buf_t0, i = True, [], t[j], j
            else:
                below = np.flatnonzero(f[i:] < off)
                j = i + int(below[0]) if below.size else n
                self._buf.append((t[i:j], f[i:j], tel[i:j]))
                if j >= n:
                    if t[-1] - self._buf_t0 > self.MAX_PASSAGE:
                        self.stats["dropped_passages"] += 1
                        self._active, self._buf = False, []
                    break
                self._active, i = False, j
                try:
                    fix = self._passage()
                except InputRejected as exc:
                    errors.append(exc)
                    continue
                if fix is not None:
                    out.append(fix)
        if errors and not out:
            raise errors[0]
        return out

    def _plausible(self, read) -> bool:
        """Whether the balise of a read (time, balise, speed) can be where the train is, given
        the reads before it alone (no odometry).

        Between two reads the train covers s2 - s1 (the balises' chainages) in t2 - t1,
        passing them with the speeds v1, v2 measured from the widths of their field peaks
        (within ``speed_tolerance``), its |acceleration| at most ``max_acceleration``: with
        the signed speeds +-v1, +-v2 (the field gives no direction) the signed distance lies
        between the areas under the lowest and the highest speed profiles that join them
        (a reversal on the way included, _reach). The directions of travel at the read for
        which some profile fits are kept: where only one fits it is known and checked at the
        next read (a neighbour behind the train at the right distance is no plausible next
        balise unless the train can have reversed in between).
        A telegram decoded wrong but naming a balise of the track (a corrupted id that passes
        the checks, cross-talk from a neighbouring track) would give a fix there with a
        decimetre sigma: unless it names a balise at a plausible place, it is withheld
        (``stats["implausible"]``). The references are the last published read and the
        reads withheld since (the last PENDING_READS): a read that agrees with any of them is
        taken (two reads that agree outvote a reference that was wrong itself), its direction
        known only if every reference it agrees with gives the same one; it becomes the
        reference. The first read has nothing to be checked against.
        """
        refs = ([self._anchor] if self._anchor is not None else []) + self._pending
        if not refs:
            self._anchor = (*read, 0)
            return True
        directions = {d for d in (self._consistent(ref, read) for ref in refs) if d is not None}
        if not directions:
            self._pending = self._pending[-(PENDING_READS - 1):] + [(*read, 0)]
            return False
        self._anchor, self._pending = (*read, directions.pop() if len(directions) == 1 else 0), []
        return True

    def _consistent(self, ref, read) -> int | None:
        """None if a read (time, balise, speed) is not plausible after the read ``ref`` (time,
        balise, speed, direction of travel there: +-1, 0 unknown), else the direction of travel
        at the read (0 if both remain possible): see _plausible."""
        p = self.params
        (t1, b1, v1, dir1), (t2, b2, v2) = ref, read
        dt = abs(t2 - t1)
        step = float(b2["position"]) - float(b1["position"])
        acc, tol = p["max_acceleration"], p["speed_tolerance"]
        # the balises' real centres differ from the track file (3.29 sigma, both)
        margin = 3.29 * math.hypot(balise_location_sigma(p, self.track, b1),
                                   balise_location_sigma(p, self.track, b2)) + 0.5
        if t2 < t1:
            step = -step
        speeds1 = (max(0.0, v1 * (1.0 - tol) - 0.5), v1 * (1.0 + tol) + 0.5)
        speeds2 = (max(0.0, v2 * (1.0 - tol) - 0.5), v2 * (1.0 + tol) + 0.5)

        def signed(speeds, d):
            return speeds if d > 0 else (-speeds[1], -speeds[0])
        directions = [d2 for d2 in (1, -1)
                      if any(_joinable(step, signed(speeds1, d1), signed(speeds2, d2), dt, acc, margin)
                             for d1 in ((dir1,) if dir1 else (1, -1)))]
        if not directions:
            return None
        return directions[0] if len(directions) == 1 else 0

    def _passage(self) -> PositionFix | None:
        p = self.params
        t = np.concatenate([c[0] for c in self._buf])
        f = np.concatenate([c[1] for c in self._buf])
        tel = np.concatenate([c[2] for c in self._buf])
        self._buf = []
        self.stats["passages"] += 1
        if len(f) < 3:
            # a blip of one or two samples: no usable peak
            self.stats["dropped_passages"] += 1
            return None
        smooth = np.convolve(f, np.ones(3) / 3.0, mode="same")
        half = 0.5 * float(smooth.max())
        above = np.flatnonzero(f >= half)
        k0, k1 = int(above[0]), int(above[-1])
        t_rise = t[k0] if k0 == 0 else t[k0 - 1] + (half - f[k0 - 1]) / (f[k0] - f[k0 - 1]) * (t[k0] - t[k0 - 1])
        t_fall = (t[k1] if k1 == len(f) - 1 else
                  t[k1] + (f[k1] - half) / (f[k1] - f[k1 + 1]) * (t[k1 + 1] - t[k1]))
        t_c = 0.5 * (t_rise + t_fall)
        duration = max(t_fall - t_rise, 1e-6)
        speed = 2.0 * self._half_width / duration
        if speed > 200.0:
            raise InputRejected("implausible", f"balise passage of {duration * 1e3:.3f} ms means "
                                               f"{speed:.0f} m/s")
        nids = np.unique(tel[tel > 0]).astype(int)
        if nids.size == 0:
            self.stats["failed_reads"] += 1
            return None
        if nids.size > 1:
            raise InputRejected("implausible", f"telegrams of several balises {nids.tolist()} in one passage")
        item = self._by_nid.get(int(nids[0]))
        if item is None:
            self.stats["unknown_id"] += 1
            raise InputRejected("unknown_id", f"telegram id {int(nids[0])} is no balise of track "
                                              f"{self.track.track_id}")
        self.stats["reads"] += 1
        read = (t_c, item, speed)
        if not self._plausible(read):
            self.stats["implausible"] += 1
            return None
        # peak-time uncertainty: noise over the field slope at half maximum, per crossing,
        # halved (in variance) by the midpoint; the interpolation error of a symmetric peak
        # cancels in the midpoint
        slope = self._rel_slope * 2.0 * half
        sigma = fix_sigma(balise_location_sigma(p, self.track, item), 0.5 * (p["field_noise"] / slope) ** 2)
        direction = 0
        if self._last_read is not None:
            t_last, last = self._last_read
            if (last["id"] != item["id"] and item.get("group") is not None
                    and last.get("group") == item.get("group")
                    and abs(item["position"] - last["position"]) <= p["group_length"]):
                direction = 1 if item["position"] > last["position"] else -1
        self._last_read = (t_c, item)
        return PositionFix(float(t_c), self.sensor, self.unit_id, self.track.track_id, str(item["id"]),
                           fix_position(p, item), float(sigma), direction)


def balise_location_sigma(params: dict, track, item: dict) -> float:
    """1-sigma [m] of one balise's real centre vs its chainage: its Q_LOCACC / LOCATION_BOUND
    where the track gives one (core/etcs/track_data.py), else the reader's ``location_sigma``."""
    q = q_locacc_of_balise(track, item)
    return params["location_sigma"] if q is None else q / LOCATION_BOUND


def fix_sigma(location_sigma: float, timing_var: float = 0.0) -> float:
    """1-sigma [m] of a balise fix: the balise's location 1-sigma [m] and the peak-timing variance
    ``timing_var`` [m^2] (the decoder's), at least MIN_FIX_SIGMA; with timing_var 0 the least
    a fix of that balise reports."""
    return max(math.sqrt(location_sigma ** 2 + timing_var), MIN_FIX_SIGMA)


def fix_position(params: dict, item: dict) -> float:
    """Train-front chainage [m] of a fix of balise ``item``: its chainage + ``antenna_offset``
    (the decoder assumes the antenna behind the front towards decreasing chainage, as the simulator)."""
    return float(item["position"] + params["antenna_offset"])


def error_model(params: dict, track, vehicle) -> ErrorModel:
    """Balise fixes for the fusion: white (reading window and peak timing in the decoder's
    stddev); fault modes: a misread telegram, an offset of a run of fixes (a balise off its
    surveyed place, revisited after a reversal). Floor: ``fix_sigma`` without timing of the
    track's most accurately located balise (``balise_location_sigma``), at least 1 mm. References: every balise of the track, window the point
    chainage + antenna_offset (``fix_position``; the refusal's 5 sigma is the margin)."""
    references = None
    floor = params["location_sigma"]
    if track is not None:
        references = ReferenceTable({str(it["id"]): ReferenceWindow(fix_position(params, it), fix_position(params, it))
                                     for it in track.items(KIND)})
        floor = min((balise_location_sigma(params, track, it) for it in track.items(KIND)), default=floor)
    return ErrorModel(KIND, "position", faults=("misread", "offset"), min_stddev=fix_sigma(floor), references=references)


SPEC = SensorSpec(
    node="eurobalise_reader", sensor=KIND, simulator=EurobaliseSimulator, decoder=EurobaliseDecoder,
    params=PARAMS, description="on-board Eurobalise reader (BTM): balise telegram -> position fix; each balise "
    "of the track sends the long telegram (1023 bit, read to 300 km/h) or the short one (341 bit, beyond): "
    "its `telegram: long | short` key (seed 001 section 1)",
    seeds=("001",), outputs=("position",), error_model=error_model,
)
