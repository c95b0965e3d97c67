"""The command line's heap: freed memory below 32 MiB is kept for reuse (glibc only).

A diagnosis allocates and frees many arrays of a few MiB (filtered signals, designs, XLA's
buffers). glibc's default gives each one above its dynamic threshold fresh pages from the
kernel and returns them on free, so every allocation pays page faults and the kernel's zeroing
of the pages: on 8-s pairs at 5 kHz a compiled ``lionjax diagnose`` process spent 3–5 s of
10–16 s in the kernel, 13 % of its cycles clearing pages. With the threshold fixed at 32 MiB and
freed memory kept (trim threshold 256 MiB, top pad 64 MiB), the same process took 10.4–11.0 s
against 11.5–13.5 s (three alternated runs each; minor page faults 0.31 M against 0.61–0.75 M;
peak RSS +5 %). Arrays of 32 MiB and more (a long record's columns) are still mapped and
returned as before, so the diagnosis' memory estimate holds. Results are unchanged: the heap
holds the same numbers.

Only the command line calls :func:`keep_freed_memory`; the library never changes the process'
allocator. It does nothing off glibc, and nothing where the user set one of glibc's own
``MALLOC_*_`` tunables (which is also the way to opt out: ``MALLOC_MMAP_THRESHOLD_=131072``
restores glibc's default start).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import sys

#: glibc's mallopt parameters (malloc.h) and the values the command line sets.
M_TRIM_THRESHOLD, M_TOP_PAD, M_MMAP_THRESHOLD = -1, -2, -3
SETTINGS = ((M_MMAP_THRESHOLD, 32 << 20), (M_TRIM_THRESHOLD, 256 << 20), (M_TOP_PAD, 64 << 20))
#: glibc's environment tunables: any of them set leaves the allocator as the user chose.
_USER_TUNABLES = (
    "MALLOC_MMAP_THRESHOLD_",
    "MALLOC_TRIM_THRESHOLD_",
    "MALLOC_TOP_PAD_",
    "MALLOC_MMAP_MAX_",
    "GLIBC_TUNABLES",
)


def keep_freed_memory(environ=None) -> bool:
    """Set :data:`SETTINGS` with glibc's ``mallopt``; returns whether they were set (False off
    Linux, off glibc, or where the environment sets the allocator already)."""
    env = os.environ if environ is None else environ
    if not sys.platform.startswith("linux") or any(k in env for k in _USER_TUNABLES):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):  # musl and others: no mallopt
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    return all(mallopt(param, value) == 1 for param, value in SETTINGS)
