"""Writing benchmark results into docs/BENCHMARKS.md: each script owns one ``## `` section."""

from __future__ import annotations

import re
from pathlib import Path

from neuenh.files import atomic_write

HEADER = "# Benchmarks\n\nMeasured numbers, each with the command that produced it.\n"


def write_section(path: Path, title: str, text: str) -> None:
    """Replace (or append) the section headed ``title`` (e.g. ``## Search (issue 4)``) of
    ``path`` with ``text`` (which starts with that heading), leaving the other sections alone."""
    path = Path(path)
    old = path.read_text() if path.exists() else HEADER
    start = old.find(title)
    if start < 0:
        new = old.rstrip("\n") + "\n\n" + text
    else:
        following = re.search(r"^## ", old[start + len(title):], re.M)
        end = start + len(title) + following.start() if following else len(old)
        new = old[:start] + text + ("\n" + old[end:] if following else "")
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(path, new.rstrip("\n") + "\n")


def publish(section: str | list[str], write: str | None, title: str) -> None:
    """Print a bench's section (its text or lines, starting with its ``title`` heading) and, with
    ``--write FILE``, replace that section of the file."""
    text = section if isinstance(section, str) else "\n".join(section)
    print(text)
    if write:
        write_section(Path(write), title, text)
        print(f"written to {write}")
