"""``neuenh serve``: the search service (REST API, dashboard, job worker) on embedded Ray.

    neuenh serve [--host 127.0.0.1] [--port 8000] [--data-dir DIR] [--ray-address ADDR] [--cpus N]
                 [--data-root DIR ...]

Every option also comes from the environment (``NEUENH_HOST``, ``NEUENH_PORT``, ``NEUENH_DATA_DIR``,
``NEUENH_RAY_ADDRESS``, ``NEUENH_RAY_NUM_CPUS``, ``NEUENH_DATA_ROOTS`` as a JSON list,
``NEUENH_API_TOKEN``, the limits ``NEUENH_MAX_*``); flags win. With no configuration at all it
serves on 127.0.0.1:8000 with an embedded Ray and the job store in ./neuenh-data. It refuses a
non-loopback --host unless NEUENH_API_TOKEN is set (the token is never a flag: flags show in ps).
Unfinished jobs in the store resume at start; Ctrl-C or SIGTERM stops the running job at a safe
point (it resumes on the next start) and shuts Ray down.
"""

from __future__ import annotations

import argparse
from pathlib import Path


def configure(p: argparse.ArgumentParser) -> None:
    """``neuenh serve``'s arguments, on the parser ``cli.main`` made for it (with its one-line help)."""
    p.description = __doc__
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.add_argument("--host", help="listen address (default 127.0.0.1)")
    p.add_argument("--port", type=int, help="listen port (default 8000; 0 picks a free one)")
    p.add_argument("--data-dir", type=Path, help="job store and artifacts (default ./neuenh-data)")
    p.add_argument("--ray-address", help="join this Ray cluster instead of starting one")
    p.add_argument("--cpus", type=int, dest="ray_num_cpus", help="CPUs of the embedded Ray (default: all)")
    p.add_argument("--data-root", type=Path, action="append", dest="data_roots", metavar="DIR",
                   help="a folder job specs may read files from (repeatable)")
    p.set_defaults(run=run)


def run(args) -> int:
    from neuenh_service.api.server import serve
    from neuenh_service.api.settings import Settings

    flags = ("host", "port", "data_dir", "ray_address", "ray_num_cpus", "data_roots")
    settings = Settings(**{k: getattr(args, k) for k in flags if getattr(args, k) is not None})
    serve(settings)
    return 0
