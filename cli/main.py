"""``neuenh``: the local command line.

Exit codes (ARCHITECTURE §4): 0 success, 1 the work failed, 2 usage error or unusable input.
A user's mistake prints one line naming what is wrong, never a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys

from neuenh.allocator import keep_freed_memory
from neuenh_service.storage import StorageError

# Command -> its line in `neuenh --help`. Its arguments come from ``cli.<command>.configure``, imported
# only when that command runs: most of those modules import torch (~1.5 s), which `neuenh --help`,
# `neuenh --version` and the other commands need not pay.
COMMANDS = {
    "fit": "fit measured materials with a model (module weights frozen)",
    "search": "run a search job in-process on embedded Ray",
    "data": "inspect measured data, materialise datasets, draw BRDF slices",
    "serve": "run the search service (API, dashboard, job worker)",
    "render": "render a sphere with a model and/or measured ground truth",
    "report": "measure every model on the RGL materials; write RESULTS.md and plots",
    "export": "write fitted materials as GLSL, ONNX or a Mitsuba 3 plugin",
    "scene": "plan a scene: per material, the cheapest model within tolerance",
    "encoder": "train a bundle's encoder: measurements -> a material's start",
}


def build_parser(argv: list[str]) -> argparse.ArgumentParser:
    """The parser for ``argv``: every command listed, the arguments of the one ``argv`` names only."""
    parser = argparse.ArgumentParser(
        prog="neuenh", description="Neural enhancement of analytical BRDF models."
    )
    parser.add_argument("--version", action="version", version=f"neuenh {_version()}")
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    # the command is the first word that is not an option (the top level has none that take a value)
    chosen = next((a for a in argv if not a.startswith("-")), None)
    for name, summary in COMMANDS.items():
        p = commands.add_parser(name, help=summary)
        if name == chosen:
            importlib.import_module(f"{__package__}.{name}").configure(p)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    args = build_parser(argv).parse_args(argv)
    keep_freed_memory()  # fits and training reuse their freed activations (neuenh.allocator)
    try:
        return args.run(args)
    except (ValueError, FileNotFoundError) as exc:
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
    except OSError as exc:  # a path the file system refuses (too long, not permitted, disk full): one line
        print(f"neuenh {args.command}: error: {exc}", file=sys.stderr)
        return 2


def _version() -> str:
    from neuenh import __version__

    return __version__


if __name__ == "__main__":
    sys.exit(main())
