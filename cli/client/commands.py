"""What every ``neuenh-client`` command shares: the parser's table of commands with the options
each takes (``--url``, ``--token``, ``--timeout``), the recurring arguments (a job id, ``--json``),
and the lines a command prints for people (notes on stderr) or machines (JSON on stdout).

A command is a module with ``add_parser(commands: Commands)``, which adds its parser with
``commands.add(name, run, help)``; ``run(args, api) -> exit code`` does the work.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable
from datetime import datetime

from .api import DEFAULT_URL, READ_TIMEOUT_S, Api

Run = Callable[[argparse.Namespace, Api], int]


class Commands:
    """The top-level parser and its sub-commands; every sub-command also takes the common options
    (before or after its name)."""

    def __init__(self, prog: str, description: str):
        self.common = argparse.ArgumentParser(add_help=False)
        self.common.add_argument("--url", default=argparse.SUPPRESS,
                                 help=f"the service (default: $NEUENH_URL or {DEFAULT_URL})")
        self.common.add_argument("--token", default=argparse.SUPPRESS,
                                 help="its bearer token (default: $NEUENH_API_TOKEN, which ps does not show)")
        self.common.add_argument("--timeout", type=float, default=argparse.SUPPRESS, metavar="SECONDS",
                                 help=f"how long to wait for an answer (default {READ_TIMEOUT_S:g}; "
                                      "download and fit wait longer)")
        self.parser = argparse.ArgumentParser(prog=prog, parents=[self.common], description=description,
                                              formatter_class=argparse.RawDescriptionHelpFormatter)
        self._commands = self.parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    def add(self, name: str, run: Run, help: str, aliases: tuple[str, ...] = ()) -> argparse.ArgumentParser:
        """A sub-command's parser; ``args.command`` is ``name`` whichever alias was typed."""
        p = self._commands.add_parser(name, parents=[self.common], help=help, description=help, aliases=list(aliases))
        p.set_defaults(run=run, command=name)
        return p


def job_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("job", metavar="JOB", help="the job id")


def json_arg(p: argparse.ArgumentParser, what: str = "print the service's answer as JSON") -> None:
    p.add_argument("--json", action="store_true", help=what)


def print_json(data) -> None:
    print(json.dumps(data, indent=2))


def note(text: str) -> None:
    """A line for the person at the terminal (stderr: stdout stays the command's result)."""
    print(text, file=sys.stderr, flush=True)


def local_time(stamp: str) -> str:
    """An ISO time stamp from the service in this machine's time zone."""
    return datetime.fromisoformat(stamp).astimezone().strftime("%Y-%m-%d %H:%M:%S")


def job_status(job: dict) -> str:
    """The status with its reason, e.g. ``STOPPED (budget)``."""
    return job["status"] + (f" ({job['reason']})" if job.get("reason") else "")


def rounds_committed(job: dict) -> int:
    return 0 if job["last_round"] is None else job["last_round"] + 1
