"""A process end that nothing can hold up: a native timer that ends the process with a given
exit code, armed before the ROS libraries' teardown (nodes/common.py ``spin``).

On a loaded host that teardown (the DDS participant's deletion, run by the garbage collector)
has been seen to block while holding the interpreter lock (test/test_stop.py), so a Python
watchdog thread never gets to run. The timer is POSIX ``timer_create`` with SIGEV_THREAD whose
notify function is the C library's ``_exit``: it runs on a thread of the C library and needs
no interpreter lock. Where that is not available (not glibc), faulthandler's native watchdog
ends the process 1 s later instead, with exit code 1 and the stuck stack on stderr.
"""
from __future__ import annotations

import ctypes
import faulthandler

_CLOCK_MONOTONIC = 1   # <time.h>
_SIGEV_THREAD = 2      # <signal.h>: call a function on a new thread when the timer expires


class _SigEvent(ctypes.Structure):
    """glibc's ``struct sigevent`` (64 bytes) with its SIGEV_THREAD member."""
    _fields_ = [("value", ctypes.c_void_p), ("signo", ctypes.c_int), ("notify", ctypes.c_int),
                ("function", ctypes.c_void_p), ("attribute", ctypes.c_void_p), ("pad", ctypes.c_int * 8)]


class _TimeSpec(ctypes.Structure):
    _fields_ = [("sec", ctypes.c_long), ("nsec", ctypes.c_long)]


class _ITimerSpec(ctypes.Structure):
    _fields_ = [("interval", _TimeSpec), ("value", _TimeSpec)]


_armed: list = []   # the timers and their events, kept alive until the process ends


def arm(seconds: float, code: int) -> bool:
    """End the process with exit code ``code`` (0..255) after ``seconds`` [s], whatever it is
    doing then. True: the native timer is armed; False: only faulthandler's (exit code 1)."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.timer_create.argtypes = [ctypes.c_int, ctypes.POINTER(_SigEvent), ctypes.POINTER(ctypes.c_void_p)]
        libc.timer_settime.argtypes = [ctypes.c_void_p, ctypes.c_int, ctypes.POINTER(_ITimerSpec), ctypes.c_void_p]
        event = _SigEvent(value=code, notify=_SIGEV_THREAD,
                          function=ctypes.cast(libc._exit, ctypes.c_void_p).value)
        timer = ctypes.c_void_p()
        if libc.timer_create(_CLOCK_MONOTONIC, ctypes.byref(event), ctypes.byref(timer)) != 0:
            raise OSError(ctypes.get_errno(), "timer_create")
        whole = int(seconds)
        spec = _ITimerSpec(value=_TimeSpec(whole, int((seconds - whole) * 1e9)))
        if libc.timer_settime(timer, 0, ctypes.byref(spec), None) != 0:
            raise OSError(ctypes.get_errno(), "timer_settime")
        _armed.append((timer, event))
        return True
    except (OSError, AttributeError):
        faulthandler.dump_traceback_later(seconds + 1.0, exit=True)
        return False
