"""The ``neuenh`` command as the tests run it.

``neuenh``: in a fresh process, as a user runs it. ``neuenh_here``: ``cli.main.main`` in this process,
for bad input that is refused before any work is done: there a fresh interpreter's imports (torch,
~2.5 s) are nearly the whole run, and the exit code, stdout and stderr are the same.
``run_probing_torch``: a command's module in a fresh process, and whether that process imported torch.
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


# runs ``python -m MODULE ARGS`` (MODULE the first argument), then says on stderr whether torch was imported
TORCH_PROBE = """
import atexit, runpy, sys
atexit.register(lambda: print("torch imported" if "torch" in sys.modules else "torch not imported", file=sys.stderr))
runpy.run_module(sys.argv.pop(1), run_name="__main__", alter_sys=True)
"""


def run_probing_torch(module: str, *args, **kw) -> tuple[subprocess.CompletedProcess, bool]:
    """``python -m MODULE ARGS`` in a fresh process (``kw`` to ``subprocess.run``: env, cwd), and
    whether it imported torch — a line the probe adds to stderr, taken off again."""
    out = subprocess.run([sys.executable, "-c", TORCH_PROBE, module, *map(str, args)], capture_output=True,
                         text=True, timeout=60, **kw)
    *stderr, probe = out.stderr.splitlines(keepends=True)
    return (subprocess.CompletedProcess(out.args, out.returncode, out.stdout, "".join(stderr)),
            probe.strip() == "torch imported")
