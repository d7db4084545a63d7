"""Fit time and fit loss per RGL material (issue 13): the enhanced model at 10,000 and 300 samples,
plain GGX at 10,000.

    python bench/bench_fit.py [--rgl DIR] [--json OUT.json] [--before BEFORE.json] [--write docs/BENCHMARKS.md]

Per material of ``../shared/data/rgl`` (skipped with a message when absent), the fit samples of the
study (``neuenh.study.heldout.draw_fit_test``, seed 0) are fitted with the default ``FitConfig`` of
the checkout it runs in, one torch thread; the wall time of ``fit_materials`` and its fit loss are
recorded. It uses only the public fit API, so the same file runs unchanged in an older checkout:
``--before`` reads that run's ``--json`` and puts both side by side (loss ratio, time ratio).
``bench/fit_before_issue13.json`` is that run at commit 351a26c (before issue 13), on this machine.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # runnable from a checkout without installing

import torch  # noqa: E402

from bench.harness import machine, machine_line, wait_quiet  # noqa: E402
from bench.report import write_section  # noqa: E402

SECTION = "## Fitting speed (issue 13)"
RGL = ROOT.parent / "shared" / "data" / "rgl"
CASES = (("enhanced GGX", 10_000), ("enhanced GGX", 300), ("plain GGX", 10_000))


def run(rgl: Path) -> dict:
    """{case: {material: (fit loss, seconds)}} for every case of CASES."""
    from neuenh.data import load_measured
    from neuenh.fit import FitConfig, fit_materials
    from neuenh.models import get_model
    from neuenh.pretrained import load_model
    from neuenh.study.heldout import draw_fit_test

    enhanced, trained = load_model("enhanced-ggx")
    models = {"enhanced GGX": (enhanced, trained), "plain GGX": (get_model("ggx"), None)}
    out: dict = {f"{m}, {n}": {} for m, n in CASES}
    for path in sorted(rgl.glob("*.bsdf")):
        material = load_measured(path)
        for label, n in CASES:
            fit, _, _ = draw_fit_test(material, n, 1, 0)
            model, table = models[label]
            result = fit_materials(model, fit, FitConfig(), seed=0, trained=table)
            out[f"{label}, {n}"][material.name] = (result.losses[0], result.wall_s)
            print(f"{label:13s} {n:6d} {material.name:28s} loss {result.losses[0]:.5f} {result.wall_s:6.2f} s",
                  flush=True)
    return out


def markdown_section(env: dict, now: dict, before: dict | None, command: str) -> str:
    lines = [SECTION, "", f"Command: `{command}`  ", machine_line(env), "",
             "Per case, the median over the 8 RGL materials of the wall time of `fit_materials` (default "
             "`FitConfig`, one thread) and the per-material fit loss. *Before*: the same file run in the "
             "checkout before issue 13 (`--before`).", ""]
    if before:
        lines += ["| case | median s before | median s now | × faster | loss now / before: median | worst | "
                  "materials within +1 % |", "|---|---:|---:|---:|---:|---:|---:|"]
    else:
        lines += ["| case | median s | median loss |", "|---|---:|---:|"]
    for case, rows in now.items():
        seconds = statistics.median(t for _, t in rows.values())
        if not before:
            lines.append(f"| {case} | {seconds:.2f} | {statistics.median(loss for loss, _ in rows.values()):.5f} |")
            continue
        old = before[case]
        old_s = statistics.median(t for _, t in old.values())
        ratios = [rows[m][0] / old[m][0] for m in rows]
        within = sum(r <= 1.01 for r in ratios)
        lines.append(f"| {case} samples | {old_s:.2f} | {seconds:.2f} | {old_s / seconds:.1f} | "
                     f"{statistics.median(ratios):.3f} | {max(ratios):.3f} | {within}/{len(ratios)} |")
    if before:
        lines += ["", "Per material, fit loss before → now (time before → now):", "",
                  "| material | " + " | ".join(now) + " |", "|---|" + "---:|" * len(now)]
        for m in next(iter(now.values())):
            cells = [f"{before[c][m][0]:.5f} → {now[c][m][0]:.5f} ({before[c][m][1]:.1f} → {now[c][m][1]:.1f} s)"
                     for c in now]
            lines.append(f"| {m} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rgl", type=Path, default=RGL, help=f"the RGL materials (default {RGL})")
    parser.add_argument("--json", type=Path, help="write the raw numbers here")
    parser.add_argument("--before", type=Path, help="a --json of the same bench in an older checkout")
    parser.add_argument("--write", metavar="PATH", help="write/replace this section of PATH (docs/BENCHMARKS.md)")
    parser.add_argument("--max-wait", type=float, default=300.0)
    args = parser.parse_args(argv)
    if not args.rgl.is_dir():
        print(f"skipped: {args.rgl} is absent (the RGL materials of ../shared)")
        return 0
    torch.set_num_threads(1)
    wait_quiet(args.max_wait, 0.3)
    env = machine()
    now = run(args.rgl)
    if args.json:
        args.json.write_text(json.dumps(now, indent=1))
    before = json.loads(args.before.read_text()) if args.before else None
    command = "python bench/bench_fit.py" + (f" --before {args.before}" if before else "") \
        + (f" --write {args.write}" if args.write else "")
    text = markdown_section(env, now, before, command)
    print(text)
    if args.write:
        write_section(Path(args.write), SECTION, text)
        print(f"written to {args.write}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
