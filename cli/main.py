"""``neuenh``: the local command line.

Exit codes (ARCHITECTURE §4): 0 success, 1 the work failed, 2 usage error or unusable input.
A user's mistake prints one line naming what is wrong, never a traceback.
"""

from __future__ import annotations

import argparse
import os
import sys

from neuenh_service.storage import StorageError

from . import data, encoder, export, fit, render, report, scene, search, serve


class UsageError(Exception):
    """Bad arguments or unusable input: reported in one line, exit code 2."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="neuenh", description="Neural enhancement of analytical BRDF models."
    )
    parser.add_argument("--version", action="version", version=f"neuenh {_version()}")
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    fit.add_parser(commands)
    search.add_parser(commands)
    data.add_parser(commands)
    serve.add_parser(commands)
    render.add_parser(commands)
    report.add_parser(commands)
    export.add_parser(commands)
    scene.add_parser(commands)
    encoder.add_parser(commands)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.run(args)
    except (UsageError, ValueError, FileNotFoundError) as exc:
        print(f"neuenh {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except StorageError as exc:  # e.g. a job store written by a newer version
        print(f"neuenh {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"neuenh {args.command}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        # The reader went away (`neuenh ... | head`): stop quietly, as SIGPIPE would.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141


def _version() -> str:
    from neuenh import __version__

    return __version__


if __name__ == "__main__":
    sys.exit(main())
