"""The ``neuenh`` command as the tests run it.

``neuenh``: in a fresh process, as a user runs it. ``neuenh_here``: ``cli.main.main`` in this process,
for bad input that is refused before any work is done: there a fresh interpreter's imports (torch,
~2.5 s) are nearly the whole run, and the exit code, stdout and stderr are the same.
"""

from __future__ import annotations

import contextlib
import io
import subprocess
import sys


def neuenh(*args, timeout: float = 180, **kw) -> subprocess.CompletedProcess:
    """``python -m neuenh_service.cli.main ARGS`` in a fresh process; ``kw`` go to ``subprocess.run`` (cwd, env)."""
    return subprocess.run([sys.executable, "-m", "neuenh_service.cli.main", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, **kw)


def neuenh_here(*args) -> subprocess.CompletedProcess:
    """``cli.main.main(ARGS)`` in this process, its output captured as ``neuenh`` captures it."""
    from neuenh_service.cli.main import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main([str(a) for a in args])
        except SystemExit as exc:  # argparse's usage errors exit 2
            code = exc.code if isinstance(exc.code, int) else 1
    return subprocess.CompletedProcess(["neuenh", *map(str, args)], code, out.getvalue(), err.getvalue())
