"""The C allocator of processes that fit and train: freed memory kept for reuse instead of handed back.

A fit step allocates and frees the same few dozen activations every step (six correction candidates
of a 10,000-sample material's validation split: 40,000 rows × 32 floats, 5 MB each; the whole step
some 200 MB). glibc's malloc, where torch's CPU tensors come from, serves a block above its mmap
threshold with fresh pages, and hands free memory at the top of its heap back to the system once it
exceeds the trim threshold (both start at 128 KiB; the threshold follows the largest freed mapping,
the trim threshold twice it). So a step whose working set is larger than that gets new pages every
time, and the kernel zeroes each on first touch: a quarter of such a step's time, an eighth of an
adaptive fit of 10,000 samples (docs/BENCHMARKS.md, "The C allocator's page faults"). ``keep_freed_memory`` serves blocks up to
glibc's largest mmap threshold from the heap and keeps up to ``retain_bytes`` of freed memory.

It is a process-wide setting, so nothing here makes it on import: the programs that fit and train —
the ``neuenh`` command, the service's server, plan and candidate processes, the fit's own worker
processes — call it when they start. Other C libraries (musl, macOS) are left alone.
"""

from __future__ import annotations

import ctypes
import platform

# mallopt(3) parameters, from glibc's <malloc.h>
M_TRIM_THRESHOLD, M_TOP_PAD, M_MMAP_THRESHOLD = -1, -2, -3
# glibc's largest mmap threshold on 64-bit systems (DEFAULT_MMAP_THRESHOLD_MAX: 4 MiB × sizeof(long));
# a block above it still gets its own mapping (a 100,000-sample batch's activations, for example)
LARGEST_MMAP_THRESHOLD = 32 << 20


def keep_freed_memory(retain_bytes: int = 1 << 30) -> bool:
    """Serve blocks of up to 32 MiB from the heap and keep up to ``retain_bytes`` of freed memory at
    its top (plus 64 MiB of headroom each time it grows) for the next allocations (module doc).
    True when glibc took the settings; False elsewhere, or when it refused one (nothing is changed
    then beyond what it took)."""
    if not 0 <= retain_bytes < 1 << 31:  # mallopt takes an int
        raise ValueError(f"retain_bytes must be in [0, 2 GiB), got {retain_bytes}")
    if platform.system() != "Linux" or platform.libc_ver()[0] != "glibc":
        return False
    mallopt = ctypes.CDLL(None).mallopt
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    settings = ((M_MMAP_THRESHOLD, LARGEST_MMAP_THRESHOLD), (M_TRIM_THRESHOLD, retain_bytes), (M_TOP_PAD, 64 << 20))
    return all(mallopt(parameter, value) == 1 for parameter, value in settings)
