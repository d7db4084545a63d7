"""Fit time and fit loss per RGL material (issue 13): the enhanced model at 10,000 and 300 samples,
plain GGX at 10,000, in this checkout and (``--before-rev``) in an older one, in the same run.

    python bench/bench_fit.py [--model SPEC] [--before-rev REV] [--rgl DIR] [--json OUT.json]
                              [--write docs/BENCHMARKS.md]

Per material of ``../shared/data/rgl`` (skipped with a message when absent), the fit samples of the
study (``neuenh.study.heldout.draw_fit_test``, seed 0) are fitted with the default protocol of
the checkout it runs in, one torch thread; the wall time of ``fit_materials`` and its fit loss are
recorded. It uses only the public fit API, so the same file runs unchanged in an older checkout:
``--before-rev`` exports that revision of the repository (``git archive``) to a temporary folder,
runs this file there first, then here, and puts both side by side (loss ratio, time ratio), so the
machine's speed of the moment is the same for both. Both fit the same ``--model``: issue 13's
comparison (``make bench``) is at 351a26c with the model shipped then (state 00001100100, 4,853
weights; the Makefile takes its files from e388c1a), since issue 14 shipped a larger one.
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # runnable from a checkout without installing

from bench.harness import absent, fitting_process, machine, machine_line, output_arguments, run_at_revision, wait_quiet, write_json  # noqa: E402
from bench.report import publish  # noqa: E402

SECTION = "## Fitting speed (issue 13)"
RGL = ROOT.parent / "shared" / "data" / "rgl"
CASES = (("enhanced GGX", 10_000), ("enhanced GGX", 300), ("plain GGX", 10_000))


def run(rgl: Path, spec: str) -> dict:
    """{case: {material: (fit loss, seconds)}} for every case of CASES; ``spec`` names the enhanced
    model (``neuenh.pretrained.load_model``)."""
    from neuenh.data import load_measured
    from neuenh.fit import fit_materials
    from neuenh.models import get_model
    from neuenh.pretrained import load_model
    from neuenh.study.heldout import draw_fit_test

    enhanced, trained = load_model(spec)
    models = {"enhanced GGX": (enhanced, trained), "plain GGX": (get_model("ggx"), None)}
    out: dict = {f"{m}, {n}": {} for m, n in CASES}
    for path in sorted(rgl.glob("*.bsdf")):
        material = load_measured(path)
        for label, n in CASES:
            fit, _, _ = draw_fit_test(material, n, 1, 0)
            model, table = models[label]
            result = fit_materials(model, fit, seed=0, trained=table)  # the default protocol
            out[f"{label}, {n}"][material.name] = (result.losses[0], result.wall_s)
            print(f"{label:13s} {n:6d} {material.name:28s} loss {result.losses[0]:.5f} {result.wall_s:6.2f} s",
                  flush=True)
    return out


def markdown_section(env: dict, now: dict, before: dict | None, command: str, model: str) -> str:
    lines = [SECTION, "", f"Command: `{command}`  ", machine_line(env) + "  ", f"Enhanced model: {model}", "",
             "Per case, the median over the 8 RGL materials of the wall time of `fit_materials` (default "
             "protocol, one thread) and the per-material fit loss. *Before*: the same file run in the "
             "checkout `--before-rev` names, run first in the same run.", ""]
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


def run_before(rev: str, args: argparse.Namespace) -> dict:
    """This file's ``run`` in the repository at ``rev``."""
    return run_at_revision(rev, Path(__file__), ["--model", str(args.model), "--rgl", str(args.rgl.resolve())])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", default="enhanced-ggx",
                        help="the enhanced model: a shipped name or a bundle folder (default enhanced-ggx)")
    parser.add_argument("--before-rev", metavar="REV", help="also run this git revision first, side by side")
    parser.add_argument("--rgl", type=Path, default=RGL, help=f"the RGL materials (default {RGL})")
    output_arguments(parser)
    args = parser.parse_args(argv)
    if absent(args.rgl, "the RGL materials of ../shared"):
        return 0
    if Path(args.model).is_dir():
        args.model = str(Path(args.model).resolve())  # the older checkout runs elsewhere
    fitting_process()
    wait_quiet(args.max_wait, 0.3)
    env = machine()
    before = run_before(args.before_rev, args) if args.before_rev else None
    now = run(args.rgl, args.model)
    if args.json:
        write_json(args.json, now)
    from neuenh.pretrained import load_model

    enhanced, _ = load_model(args.model)
    name = Path(args.model).name if Path(args.model).is_dir() else args.model
    model = f"{name}, state {enhanced.state}, {sum(p.numel() for p in enhanced.parameters()):,} weights"
    command = " ".join(["python bench/bench_fit.py", *(argv if argv is not None else sys.argv[1:])])
    text = markdown_section(env, now, before, command, model)
    publish(text.splitlines(), args.write, SECTION)  # lines: the form older checkouts' publish takes
    return 0


if __name__ == "__main__":
    sys.exit(main())
