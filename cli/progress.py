"""Progress on a stream. ``ProgressDisplay``: a search's, one live line on a terminal, a line per
committed round otherwise; ``neuenh search`` shows its own job with it, ``neuenh-client`` a served one
(without importing the orchestrator or torch: ``watch`` answers in a fraction of a second).
``StepBar``: steps of a known count (a scene plan's rungs, a fit's materials) as a live bar."""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, TextIO

if TYPE_CHECKING:
    from neuenh_service.orchestrator.runner import Progress


class ProgressDisplay:
    """One live line on a terminal (round, candidates done/total, best loss, elapsed); a line per
    committed round otherwise."""

    def __init__(self, stream: TextIO):
        self.stream = stream
        self.live = stream.isatty()

    def __call__(self, p: Progress) -> None:
        best = f"{p.best_val_loss:.5f}" if p.best_val_loss is not None else "-"
        text = (f"round {p.round}  candidates {p.done}/{p.total}  best {best}  "
                f"{_clock(p.elapsed_s)}  {p.message}")
        if self.live:
            self.stream.write("\r\033[K" + text)
            self.stream.flush()
        elif p.message in ("committed", "converged", "cancelled"):
            self.stream.write(f"round {p.round}: {p.message}, winner {p.state} {p.score} {best} at {_clock(p.elapsed_s)}\n")

    def note(self, text: str) -> None:
        self.stream.write(text + "\n")

    def done(self) -> None:
        if self.live:
            self.stream.write("\n")


class StepBar:
    """A live bar on a terminal (done/total, seconds since it was made, what is running); a line per
    step otherwise, or nothing at all when ``quiet_unless_live`` (output for a person watching only)."""

    def __init__(self, stream: TextIO, quiet_unless_live: bool = False):
        self.stream, self.live, self.start = stream, stream.isatty(), time.monotonic()
        self.quiet = quiet_unless_live and not self.live

    def __call__(self, what: str, done: int, total: int) -> None:
        if self.quiet:
            return
        width = 24
        filled = int(width * done / max(total, 1))
        text = f"[{'#' * filled}{'.' * (width - filled)}] {done}/{total} {time.monotonic() - self.start:5.0f} s  {what}"
        self.stream.write(("\r\033[K" + text[:110]) if self.live else text + "\n")
        self.stream.flush()

    def note(self, text: str) -> None:
        if not self.quiet:
            self.stream.write(text + "\n")

    def done(self) -> None:
        if self.live:
            self.stream.write("\n")


def _clock(seconds: float) -> str:
    m, s = divmod(int(seconds), 60)
    return f"{m:02d}:{s:02d}"
