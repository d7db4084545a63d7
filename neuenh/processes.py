"""Worker processes that end with the process that started them.

A ``neuenh report`` or ``neuenh fit --jobs N`` killed with SIGKILL (a test's timeout, the OOM killer, a
scheduler) cannot ask its pool's workers to stop; without this they fit on, for minutes, on cores someone
else now wants (docs/BENCHMARKS.md, "Test suite time", stop 68: an orphaned report worker took an hour of
a core). Call ``die_with_parent`` first thing in a worker (a pool's ``initializer``).
"""

from __future__ import annotations

import ctypes
import signal

_PR_SET_PDEATHSIG = 1  # linux/prctl.h


def die_with_parent() -> None:
    """SIGKILL this process when the thread that started it ends, which for a pool is the process that
    created it (Linux ``PR_SET_PDEATHSIG``; elsewhere nothing)."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL)
    except (OSError, AttributeError):
        pass
