"""Where a device's text lines come from: a file, a UDP port or a serial device (NMEA 0183).

Every stream is read without blocking: ``read`` returns the complete lines that have arrived
(at most ``max_lines``), ``[]`` when none has, and ``eof`` tells a file that has ended. One
datagram holds whole lines (a receiver's or a multiplexer's NMEA over UDP, port 10110 by
custom); a serial port is a byte stream cut into lines by core/ingest/nmea.py's LineBuffer.
The serial port is set up with the standard library's termios (raw, 8N1, ``baud``).
"""
from __future__ import annotations

import errno
import os
import socket
import termios
import tty

from .nmea import LineBuffer

BAUDS = (4800, 9600, 19200, 38400, 57600, 115200, 230400, 460800, 921600)


class StreamError(OSError):
    """A stream that cannot be opened, with the reason in one line."""


class FileLines:
    """The lines of a text file (a logged NMEA stream)."""

    def __init__(self, path: str):
        try:
            self._fh = open(path, "rb")
        except OSError as exc:
            raise StreamError(f"NMEA file {path!r}: {exc.strerror}") from None
        self.eof = False

    def read(self, max_lines: int = 100) -> list[bytes]:
        out = []
        while len(out) < max_lines:
            line = self._fh.readline()
            if not line:
                self.eof = True
                break
            if line.strip():
                out.append(line.strip())
        return out

    def close(self) -> None:
        self._fh.close()


class UdpLines:
    """The lines of the datagrams arriving at ``address``:``port`` (127.0.0.1 keeps it on the host)."""

    eof = False

    def __init__(self, address: str, port: int):
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self._sock.bind((address, port))
        except OSError as exc:
            self._sock.close()
            raise StreamError(f"UDP {address}:{port}: {exc.strerror}") from None
        self._sock.setblocking(False)

    @property
    def port(self) -> int:
        return self._sock.getsockname()[1]

    def read(self, max_lines: int = 100) -> list[bytes]:
        out = []
        while len(out) < max_lines:
            try:
                data = self._sock.recv(65536)
            except BlockingIOError:
                break
            out += [line.strip() for line in data.splitlines() if line.strip()]
        return out

    def close(self) -> None:
        self._sock.close()


class SerialLines:
    """The lines of a serial device (``/dev/ttyUSB0``, a pseudo-terminal) at ``baud``."""

    eof = False

    def __init__(self, path: str, baud: int):
        if baud not in BAUDS:
            raise StreamError(f"serial baud rate {baud} is none of {', '.join(map(str, BAUDS))}")
        try:
            self._fd = os.open(path, os.O_RDONLY | os.O_NOCTTY | os.O_NONBLOCK)
        except OSError as exc:
            raise StreamError(f"serial device {path!r}: {exc.strerror}") from None
        try:
            if os.isatty(self._fd):
                tty.setraw(self._fd)
                attrs = termios.tcgetattr(self._fd)
                attrs[4] = attrs[5] = getattr(termios, f"B{baud}")   # input and output speed
                termios.tcsetattr(self._fd, termios.TCSANOW, attrs)
        except termios.error as exc:
            os.close(self._fd)
            raise StreamError(f"serial device {path!r}: {exc}") from None
        self._lines = LineBuffer()

    def read(self, max_lines: int = 100) -> list[bytes]:
        out = []
        while len(out) < max_lines:
            try:
                data = os.read(self._fd, 4096)
            except OSError as exc:
                if exc.errno in (errno.EAGAIN, errno.EWOULDBLOCK):
                    break
                raise
            if not data:
                break
            out += self._lines.feed(data)
        return out

    def close(self) -> None:
        os.close(self._fd)
