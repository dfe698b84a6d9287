"""Raw signal blocks: the one representation of raw sensor data in the core.

A block holds ``n_samples x n_channels`` samples taken at a fixed sample rate from
one device, starting at ``t0``. Simulated devices produce blocks, device drivers and
bags deliver them (train_localization_msgs/RawBlock), and every decoder consumes
them, so simulated, recorded and ingested data go through the same code
(raw signals travel in blocks: docs/nodes.md).

Samples are stored as float32, like the message: a simulated block is rounded to
float32 when it is made, so decoding it live or after a bag round trip is identical.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np


class InputRejected(ValueError):
    """Raised for input that must not reach a decoder or the filter.

    ``reason`` is a short machine-readable key used for counting in diagnostics
    (e.g. ``"nan"``, ``"shape"``, ``"stamp_back"``, ``"duplicate"``, ``"channels"``).
    """

    def __init__(self, reason: str, message: str):
        super().__init__(f"{reason}: {message}")
        self.reason = reason
        self.message = message

    def __reduce__(self):   # pickles with both arguments (parallel offline replay returns them)
        return type(self), (self.reason, self.message)


# longest id a message may carry (sensor, unit, track, reference, section, channel): the
# equipment's ids are a few characters; a longer one is refused and never echoed whole
MAX_ID_LENGTH = 64


def require_short(kind: str, **ids: str) -> None:
    """Raises InputRejected("too_long") naming the first of ``ids`` longer than MAX_ID_LENGTH."""
    for name, value in ids.items():
        if len(value) > MAX_ID_LENGTH:
            raise InputRejected("too_long", f"{kind}.{name} of {len(value)} characters (at most "
                                            f"{MAX_ID_LENGTH}): {value[:16]!r}...")


@dataclass(frozen=True)
class RawBlock:
    """``n_samples`` samples of ``len(channels)`` channels from one device.

    t0: time of the first sample [s]; sample_rate [Hz]; data: float32 array of shape
    (n_samples, n_channels); seq: per-device block counter.
    """

    sensor: str
    unit_id: str
    seq: int
    t0: float
    sample_rate: float
    channels: tuple[str, ...]
    units: tuple[str, ...]
    data: np.ndarray = field(repr=False)

    @property
    def n_samples(self) -> int:
        return int(self.data.shape[0])

    @property
    def duration(self) -> float:
        """Time covered by the block [s] (n_samples / sample_rate)."""
        return self.n_samples / self.sample_rate

    @property
    def t_end(self) -> float:
        """Time of the sample after the last one [s]."""
        return self.t0 + self.duration

    def times(self) -> np.ndarray:
        """Sample times [s]."""
        return self.t0 + np.arange(self.n_samples) / self.sample_rate

    def channel(self, name: str) -> np.ndarray:
        """Samples of one channel, by name."""
        return self.data[:, self.channels.index(name)]

    @classmethod
    def from_flat(cls, sensor, unit_id, seq, t0, sample_rate, channels, units, flat) -> "RawBlock":
        """Build from the message layout (row-major flat samples), validating it.

        Raises InputRejected for NaN/inf samples, a length that is not a multiple of
        the channel count, a non-positive or non-finite sample rate, or a units list
        that does not match the channels.
        """
        channels = tuple(channels)
        units = tuple(units)
        require_short("RawBlock", sensor=sensor, unit_id=unit_id)
        if len(channels) > MAX_CHANNELS:
            raise InputRejected("channels", f"{len(channels)} channels (at most {MAX_CHANNELS})")
        for name in (*channels, *units):
            require_short("RawBlock", channel=name)
        flat = np.asarray(flat, dtype=np.float32)
        if not channels:
            raise InputRejected("channels", "block has no channels")
        if len(units) != len(channels):
            raise InputRejected("shape", f"{len(units)} units for {len(channels)} channels")
        sample_rate, t0 = float(sample_rate), float(t0)
        if not (math.isfinite(sample_rate) and sample_rate > 0.0):
            raise InputRejected("sample_rate", f"sample rate {sample_rate!r} Hz is not a positive number")
        if not SAMPLE_RATE_RANGE[0] <= sample_rate <= SAMPLE_RATE_RANGE[1]:
            raise InputRejected("sample_rate", f"sample rate {sample_rate!r} Hz outside {SAMPLE_RATE_RANGE[0]:g} "
                                f".. {SAMPLE_RATE_RANGE[1]:g} Hz")
        if flat.size > MAX_BLOCK_VALUES:
            raise InputRejected("too_large", f"{flat.size} values in one block (at most {MAX_BLOCK_VALUES}: "
                                "blocks are tens of milliseconds)")
        if not abs(t0) <= MAX_STAMP:
            raise InputRejected("stamp", f"first-sample stamp {t0!r} s is not within +-{MAX_STAMP:g} s")
        if flat.size == 0 or flat.size % len(channels):
            raise InputRejected(
                "shape", f"{flat.size} samples cannot be split into {len(channels)} channels")
        # one pass: a float64 sum of float32 samples cannot overflow, so it is finite
        # exactly when every sample is
        if not math.isfinite(np.add.reduce(flat, dtype=np.float64)):
            raise InputRejected("nan", f"{int(np.count_nonzero(~np.isfinite(flat)))} samples are NaN or inf")
        t0 = round(t0 * 1_000_000_000) / 1_000_000_000  # whole ns: survives a stamp round trip
        return cls(sensor, unit_id, int(seq), t0, sample_rate, channels, units,
                   flat.reshape(-1, len(channels)))

    @classmethod
    def from_samples(cls, sensor, unit_id, seq, t0, sample_rate, channels, units, samples) -> "RawBlock":
        """Build from a (n_samples, n_channels) array, rounding to float32."""
        samples = np.asarray(samples, dtype=np.float32)
        return cls.from_flat(sensor, unit_id, seq, t0, sample_rate, channels, units, samples.reshape(-1))


# A raw block's sample rate [Hz] (below: a block would span ages; above: no device here
# samples faster) and its size (blocks are tens of milliseconds; a huge one would stall the
# decoder and its memory)
SAMPLE_RATE_RANGE = (1.0, 1.0e8)
MAX_BLOCK_VALUES = 2_000_000
MAX_CHANNELS = 64       # the devices have 1-12
MAX_STAMP = 2.0 ** 31   # [s]: the reach of a ROS time stamp (int32 seconds)
RESYNC_BLOCKS = 3   # rejected blocks in a row that continue one another: the device's sequence again


class BlockSequenceGuard:
    """Checks that the blocks of one device arrive in order and are not repeated.

    A block is rejected if its seq was already seen (``duplicate``), if it starts
    before the end of the previous accepted block by more than half a sample
    (``stamp_back``), or if its channel layout differs from the expected one
    (``channels``). Gaps (lost blocks) are accepted and counted in ``gaps``.

    ``check`` only looks; ``commit`` makes a block the reference for the next ones, once
    it was decoded: a block that is rejected later (by the decoder) sets nothing. One bad
    block that was accepted (a stamp far ahead, a seq near 2^32) would make every later
    one a duplicate or go back in time: when RESYNC_BLOCKS rejected blocks in a row
    continue one another (consecutive seq, contiguous in time), the guard takes them as
    the device's sequence again (counted in ``resyncs``).
    """

    def __init__(self, expected_channels: tuple[str, ...] | None = None):
        self.expected_channels = tuple(expected_channels) if expected_channels else None
        self._last: dict[str, RawBlock] = {}
        self._refused: dict[str, list[RawBlock]] = {}   # rejected blocks in a row that continue one another
        self.gaps = 0
        self.resyncs = 0

    def check(self, block: RawBlock) -> None:
        if self.expected_channels is not None and block.channels != self.expected_channels:
            raise InputRejected(
                "channels", f"channels {block.channels} differ from expected {self.expected_channels}")
        last = self._last.get(block.unit_id)
        if last is None:
            return
        if block.seq <= last.seq:
            self._refuse(block, InputRejected("duplicate", f"{block.unit_id}: seq {block.seq} after {last.seq}"))
        elif block.t0 < last.t_end - 0.5 / block.sample_rate:
            self._refuse(block, InputRejected(
                "stamp_back", f"{block.unit_id}: block starts at {block.t0:.6f} s, "
                f"before the end of the previous one at {last.t_end:.6f} s"))

    def _refuse(self, block: RawBlock, exc: InputRejected) -> None:
        run = self._refused.get(block.unit_id, [])
        prev = run[-1] if run else None
        if prev is not None and block.seq == prev.seq + 1 and abs(block.t0 - prev.t_end) <= 0.5 / block.sample_rate:
            run = run + [block]
        else:
            run = [block]
        self._refused[block.unit_id] = run
        if len(run) >= RESYNC_BLOCKS:
            # the device's sequence again: passed on, and the reference once decoded. The run is
            # kept until then: should the decoder refuse this block, the next one that continues
            # it passes too (else one undecodable block would use the resync up for good)
            return
        raise exc

    def commit(self, block: RawBlock) -> None:
        last = self._last.get(block.unit_id)
        run = self._refused.get(block.unit_id)
        if run and run[-1] is block:
            self.resyncs += 1
        elif last is not None and block.seq > last.seq + 1:
            self.gaps += block.seq - last.seq - 1
        self._last[block.unit_id] = block
        self._refused[block.unit_id] = []
