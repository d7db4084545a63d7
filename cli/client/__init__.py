"""``neuenh-client``: the search service from the command line.

    neuenh-client submit SPEC.yaml [--wait]     # the job id on stdout; --wait follows it to the end
    neuenh-client status [JOB]                  # a job, or the service, its cluster and recent jobs
    neuenh-client jobs [--status RUNNING]       # jobs, newest first (also: list)
    neuenh-client history JOB                   # committed rounds as a table
    neuenh-client watch JOB                     # follow a job until it ends
    neuenh-client cancel JOB                    # also: cancel --plan PLAN
    neuenh-client download JOB [-o DIR|FILE.zip]
    neuenh-client export JOB --format glsl|onnx|mitsuba [-o DIR] [--material NAME ...]
    neuenh-client fit JOB measurements.npz ...  # fit materials with the job's model, on the service
    neuenh-client plan SCENE.yaml [--wait] [-o DIR]  # plan a scene on the service (neuenh scene plan)

The service is ``--url`` or ``$NEUENH_URL`` (default http://127.0.0.1:8000); its token ``--token``
or ``$NEUENH_API_TOKEN`` (prefer the variable: flags show in ``ps``). ``--json`` prints what the
service answered, for machines; people get tables and a progress display (on stderr).

Exit codes (ARCHITECTURE §4): 0 success, 1 the job failed (or was cancelled) or the service failed
(a damaged stored file: its operator restores it), 2 usage error (a bad spec or table, no such
job, a request the service refuses), 3 the service cannot be reached, does not accept the token,
or is busy (429: retry later). Every error is one line, never a traceback.
"""

from __future__ import annotations

import argparse
import os
import sys

from . import cancel, download, export, fit, history, jobs, plan, status, submit, watch
from .api import DEFAULT_URL, READ_TIMEOUT_S, Api, ClientError
from .commands import Commands

# In the order ``--help`` lists them: each module adds its command with ``add_parser(Commands)``.
COMMANDS = (submit, status, jobs, history, watch, cancel, download, export, fit, plan)


def build_parser() -> argparse.ArgumentParser:
    commands = Commands(prog="neuenh-client", description=__doc__)
    for module in COMMANDS:
        module.add_parser(commands)
    return commands.parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    prefix = f"neuenh-client {args.command}"
    args.timeout = getattr(args, "timeout", None)  # None: each call's own default
    url = getattr(args, "url", None) or os.environ.get("NEUENH_URL") or DEFAULT_URL
    token = getattr(args, "token", None) or os.environ.get("NEUENH_API_TOKEN") or None
    try:
        api = Api(url, token, read_timeout=args.timeout or READ_TIMEOUT_S)
        try:
            return args.run(args, api)
        finally:
            api.close()
    except BrokenPipeError:
        # The reader went away (`neuenh-client history JOB | head`): stop quietly, as SIGPIPE would.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
    except ClientError as exc:
        print(f"{prefix}: error: {exc}", file=sys.stderr)
        return exc.code
    except (ValueError, OSError) as exc:  # a bad spec or table (SpecError, TableError), a file not there
        print(f"{prefix}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{prefix}: interrupted", file=sys.stderr)
        return 130
