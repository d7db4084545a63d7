"""Following a job from the client until it ends (``watch``, ``submit --wait``).

Committed rounds come from ``GET /v1/jobs/{id}/history?since_round=k``, polled incrementally, so
none is missed however fast the job runs; on a terminal the live progress of the round in flight
comes from ``GET /v1/jobs/{id}``. Both are shown by ``cli.progress.ProgressDisplay``, as ``neuenh
search`` shows them: a live line on a terminal (kept, one per committed round), one line per
committed round otherwise. Losing the service for a while (a restart: jobs resume) is waited out
for ``reconnect_s`` before giving up with exit code 3.
"""

from __future__ import annotations

import argparse
import sys
import time
from datetime import datetime
from types import SimpleNamespace
from typing import TextIO

from ..progress import ProgressDisplay
from .api import UNREACHABLE, Api, ClientError
from .commands import job_status, note, print_json, rounds_committed

SUCCESS = ("CONVERGED", "STOPPED")


def follow_args(p: argparse.ArgumentParser) -> None:
    """``--interval`` and ``--reconnect``, for the commands that follow a job."""
    p.add_argument("--interval", type=float, default=0.5, metavar="SECONDS", help="how often to poll (default 0.5)")
    p.add_argument("--reconnect", type=float, default=60.0, metavar="SECONDS",
                   help="how long to wait out a service that went away, e.g. restarting (default 60)")


def follow_to_end(api: Api, job_id: str, args) -> int:
    """Follow ``job_id`` on stderr, say how it ended (``--json``: print the finished job) and return
    its exit code; Ctrl-C stops following (130), not the job."""
    try:
        job = follow(api, job_id, sys.stderr, interval=args.interval, reconnect_s=args.reconnect)
    except KeyboardInterrupt:
        note(f"stopped watching job {job_id}; it keeps running on the service "
             f"(neuenh-client cancel {job_id} stops it)")
        return 130
    code, line = outcome(job)
    note(line)
    if args.json:
        print_json(job)
    return code


def follow(api: Api, job_id: str, stream: TextIO, *, interval: float = 0.5, reconnect_s: float = 60.0) -> dict:
    """Show ``job_id``'s rounds and progress on ``stream`` until it is terminal; return the job."""
    api.job(job_id)  # no such job, or no service at all: fail at once, retry nothing
    return _Follower(api, job_id, stream, interval, reconnect_s).run()


class _Follower:
    def __init__(self, api: Api, job_id: str, stream: TextIO, interval: float, reconnect_s: float):
        self.api, self.job_id, self.interval, self.reconnect_s = api, job_id, interval, reconnect_s
        self.display = ProgressDisplay(stream)
        self.line_open = False  # a live line is on screen without its newline
        self.origin: float | None = None  # when round 0 started: round lines show the time since

    def run(self) -> dict:
        since, status, shown = 0, None, None
        try:
            while True:
                history = self._poll(self.api.history, self.job_id, since)
                for r in history["rounds"]:
                    self._show_round(r, by_fit=history["score"] == "fit")
                since = history["next_since_round"]
                if history["terminal"]:
                    break
                if history["status"] != status:
                    status = history["status"]
                    self._note(f"job {self.job_id}: {status.lower()}")
                if self.display.live:  # the round in flight, on a terminal only
                    progress = self._poll(self.api.job, self.job_id).get("progress")
                    if progress and progress != shown:
                        self.display(SimpleNamespace(**progress))
                        shown, self.line_open = progress, True
                time.sleep(self.interval)
        finally:  # Ctrl-C included: leave the terminal on a fresh line
            self._close_line()
        return self._poll(self.api.job, self.job_id)

    def _show_round(self, r: dict, by_fit: bool) -> None:
        """A committed round's line; ``by_fit``: the job selects by its fit score (search.score: fit)."""
        if self.origin is None:
            self.origin = _seconds(r["started_at"])
        n = len(r["candidates"])
        self.display(SimpleNamespace(round=r["round"], done=n, total=n,
                                     best_val_loss=r["winner_fit_score"] if by_fit else r["winner_val_loss"],
                                     score="fit score" if by_fit else "val",
                                     state=r["winner_state"], elapsed_s=_seconds(r["finished_at"]) - self.origin,
                                     message="converged" if r["converged"] else "committed"))
        self.line_open = self.display.live
        self._close_line()  # a committed round stays on screen

    def _poll(self, call, *args):
        """``call(*args)``, waiting out a service that cannot be reached for up to ``reconnect_s``."""
        lost_at = None
        while True:
            try:
                return call(*args)
            except ClientError as exc:
                if exc.code != UNREACHABLE or exc.status is not None:  # a refused token is final
                    raise
                if lost_at is None:
                    lost_at = time.monotonic()
                    self._note(f"lost {self.api.url}; trying again for {self.reconnect_s:g} s")
                if time.monotonic() - lost_at > self.reconnect_s:
                    raise
                time.sleep(min(2.0, max(self.interval, 0.1)))

    def _note(self, text: str) -> None:
        self._close_line()
        self.display.note(text)

    def _close_line(self) -> None:
        if self.line_open:
            self.display.done()
            self.line_open = False


def outcome(job: dict) -> tuple[int, str]:
    """The exit code of a finished job (0 converged or stopped, 1 failed or cancelled) and a line
    saying how it ended."""
    line = f"job {job['id']}: {job_status(job)} after {rounds_committed(job)} round(s)"
    if job.get("current_state"):
        line += f", state {job['current_state']}"
    if job.get("error"):
        line += f": {job['error']}"
    return (0 if job["status"] in SUCCESS else 1), line


def _seconds(stamp: str) -> float:
    return datetime.fromisoformat(stamp).timestamp()
