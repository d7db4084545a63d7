"""The system libLLVM Dr.Jit's LLVM backend compiles with: found once, shared by the Mitsuba export
(``neuenh.export.mitsuba``) and the fit's compiled kernel (``neuenh.fit.jit``).

Dr.Jit 1.5 emits ``llvm.minimum``/``maximum``, which LLVM 15 and 16 cannot select on x86 and abort
on, so the library must be version 17 or newer (Debian 12: ``apt-get install libllvm19``; ``make
mitsuba``). Dr.Jit reads its path from ``DRJIT_LIBLLVM_PATH`` when it first initialises its LLVM
backend.
"""

from __future__ import annotations

import glob
import os
import re

LLVM_MIN = 17  # the oldest libLLVM Dr.Jit 1.5's kernels compile with on x86 (module doc)
LLVM_DIRS = ("/usr/lib/x86_64-linux-gnu", "/usr/lib/aarch64-linux-gnu", "/usr/lib64", "/usr/lib", "/usr/local/lib")


def find_libllvm() -> str | None:
    """The newest ``libLLVM`` of version ``LLVM_MIN`` or newer in the usual library folders, or None."""
    found = []
    for folder in LLVM_DIRS:
        for path in glob.glob(os.path.join(folder, "libLLVM*.so*")):
            match = re.search(r"libLLVM(?:-|\.so\.)(\d+)", os.path.basename(path))
            if match and int(match.group(1)) >= LLVM_MIN:
                found.append((int(match.group(1)), path))
    return max(found)[1] if found else None


def point_drjit_at_libllvm() -> bool:
    """Set ``DRJIT_LIBLLVM_PATH`` to ``find_libllvm()`` unless it is set; whether a path is set now."""
    if not os.environ.get("DRJIT_LIBLLVM_PATH"):
        path = find_libllvm()
        if path is None:
            return False
        os.environ["DRJIT_LIBLLVM_PATH"] = path
    return True
