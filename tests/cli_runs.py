"""The ``neuenh`` command as the tests run it.

``neuenh``: in a fresh process, as a user runs it — each command's own tests run it so at least once,
and wherever the process is what is checked (its imports, its children, a kill, a resume).
``neuenh_on_a_terminal``: ``neuenh`` with its stderr on a pseudo-terminal (what a person watching sees).
``neuenh_here``: ``cli.main.main`` in this process, wherever what is checked is the command's exit
code, output and files: the same code from the parsed arguments on, without a fresh interpreter's
imports (torch: ~2.5 s of CPU, which the suite, CPU-bound on two cores, pays in wall time).
``run_probing_torch``: a command's module in a fresh process, and whether that process imported torch.
"""

from __future__ import annotations

import contextlib
import io
import os
import pty
import subprocess
import sys
import threading
import unittest.mock


def _command(args) -> list[str]:
    return [sys.executable, "-m", "neuenh_service.cli.main", *map(str, args)]


def neuenh(*args, timeout: float = 180, **kw) -> subprocess.CompletedProcess:
    """``python -m neuenh_service.cli.main ARGS`` in a fresh process; ``kw`` go to ``subprocess.run`` (cwd, env)."""
    return subprocess.run(_command(args), capture_output=True, text=True, timeout=timeout, **kw)


def neuenh_on_a_terminal(*args, timeout: float = 180) -> subprocess.CompletedProcess:
    """``neuenh ARGS`` as ``neuenh`` runs it, but with stderr on a pseudo-terminal (stdout a pipe): its
    ``stderr`` is what the terminal received, line ends as the command wrote them."""
    master, slave = pty.openpty()
    proc = subprocess.Popen(_command(args), stdout=subprocess.PIPE, stderr=slave, text=True)
    os.close(slave)
    received: list[bytes] = []

    def read() -> None:  # until EIO (the process closed the terminal's last handle) or the end
        with contextlib.suppress(OSError):
            while chunk := os.read(master, 4096):
                received.append(chunk)

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    try:
        stdout, _ = proc.communicate(timeout=timeout)
        reader.join(timeout=10)
    finally:
        os.close(master)
    terminal = b"".join(received).decode().replace("\r\n", "\n")  # the terminal's own CR LF for each LF
    return subprocess.CompletedProcess(proc.args, proc.returncode, stdout, terminal)


def neuenh_here(*args) -> subprocess.CompletedProcess:
    """``cli.main.main(ARGS)`` in this process, its output captured as ``neuenh`` captures it."""
    from neuenh_service.cli.main import main

    return run_here(main, "neuenh", args)


def run_here(main, name: str, args, env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    """``main(ARGS)`` of a command in this process — stdout, stderr and the exit code captured as
    ``subprocess.run`` would — with ``env``, when given, as the whole environment while it runs."""
    out, err = io.StringIO(), io.StringIO()
    environ = unittest.mock.patch.dict(os.environ, env, clear=True) if env is not None else contextlib.nullcontext()
    with environ, contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main([str(a) for a in args])
        except SystemExit as exc:  # argparse's usage errors exit 2
            code = exc.code if isinstance(exc.code, int) else 1
    return subprocess.CompletedProcess([name, *map(str, args)], code, out.getvalue(), err.getvalue())


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
