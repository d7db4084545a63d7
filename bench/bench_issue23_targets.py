"""Issue 23's targets on the visible RGL materials (evaluation only: nothing is chosen on them), by
the report's own data-efficiency curves (``neuenh.study.efficiency``) and its contenders
(``neuenh.study.report.build_contenders``): the enhanced model fitted at the latent and at the
adaptive capacity, plain GGX and NBRDF, per material, protocol and fit size.

    python bench/bench_issue23_targets.py --json OUT.json [--rgl ../shared/data/rgl] [--model enhanced-ggx]
                                          [--jobs 2] [--sizes N ...] [--stop-at HH:MM] [--write docs/BENCHMARKS.md]

``neuenh report --efficiency`` measures the same points (same draws, seed 0, 10,000 test pairs),
plus renders and every other model, in one go; this runs only what the targets need, cheapest and
most needed first (the units of ``UNITS``: every material of one before the next), keeps each unit in
``--json`` as it finishes (running the command again measures only the rest), and starts no unit
after ``--stop-at`` (UTC), so a deadline leaves complete rows rather than half of each. It prints,
and with ``--write`` records, the targets (``neuenh.study.targets``) and per fit size the adaptive
fit's chosen capacities, parameters per material and fit time beside NBRDF's.
"""

from __future__ import annotations

import argparse
import concurrent.futures
import datetime as dt
import json
import multiprocessing
import statistics
import sys
import time
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # runnable from a checkout without installing

from bench.harness import fitting_process, machine, machine_line, write_json  # noqa: E402
from bench.report import publish  # noqa: E402
from neuenh.study.registry import ENHANCED, ENHANCED_ADAPTIVE  # noqa: E402

SECTION = "## Issue 23's targets on the visible 8"
N_TEST = 10_000
CHEAP = (ENHANCED, "ggx", "nbrdf")
EVERY = (ENHANCED, ENHANCED_ADAPTIVE, "ggx", "nbrdf")
# (protocol, fit size, contenders), in the order they run: the figures no earlier run measured first
# (the adaptive fit at 3,000 mirror pairs, then at 100 to 1,000), the latent fit, GGX and NBRDF at
# 10,000 uniform pairs (docs/RESULTS.md has them) next, the adaptive fit at 10,000 (the dearest) last
UNITS = [("mirror", 3000, EVERY),
         *((protocol, n, EVERY) for n in (100, 300, 1000) for protocol in ("uniform", "mirror")),
         ("uniform", 10_000, CHEAP), ("uniform", 10_000, (ENHANCED_ADAPTIVE,))]


def unit_key(protocol: str, n: int, contenders: tuple[str, ...], material: str) -> str:
    return f"{protocol}/{n}/{'+'.join(contenders)}/{material}"


def measure(model: str, path: Path, protocol: str, n: int, contenders: tuple[str, ...], stop_at: float | None):
    """One unit in a worker process: the curve's points, or None when it would start after ``stop_at``."""
    if stop_at is not None and time.time() > stop_at:
        return None

    from neuenh.data.measured import load_measured
    from neuenh.study.efficiency import measure_curve
    from neuenh.study.report import StudySettings, build_contenders

    fitting_process()
    settings = StudySettings(rgl=path.parent, model=model, baselines=ROOT / "models" / "baselines", out=ROOT,
                             command="")
    points = measure_curve(load_measured(path), build_contenders(settings, contenders), (n,), (protocol,),
                           n_test=N_TEST, seed=0)
    return [p.row() for p in points]


def run(args) -> dict:
    from neuenh.study.report import find_materials

    data = _read(args.json)
    stop_at = None
    if args.stop_at:
        hour, minute = map(int, args.stop_at.split(":"))
        now = dt.datetime.now(dt.timezone.utc)
        stop_at = now.replace(hour=hour, minute=minute, second=0).timestamp()
    paths = find_materials(args.rgl, tuple(args.materials) if args.materials else None)
    todo = [(protocol, n, c, p) for protocol, n, c in UNITS for p in paths
            if unit_key(protocol, n, c, p.stem) not in data["units"] and (not args.sizes or n in args.sizes)]
    with concurrent.futures.ProcessPoolExecutor(args.jobs, mp_context=multiprocessing.get_context("fork")) as pool:
        futures = {pool.submit(measure, args.model, p, protocol, n, c, stop_at): (protocol, n, c, p)
                   for protocol, n, c, p in todo}
        for future in concurrent.futures.as_completed(futures):
            protocol, n, c, p = futures[future]
            points = future.result()
            if points is None:
                continue
            data = _keep(args.json, unit_key(protocol, n, c, p.stem), points)
            print(f"{dt.datetime.now(dt.timezone.utc):%H:%M} {protocol} {n:>6} {p.stem:24s} "
                  + ", ".join(f"{x['contender']} {x['heldout_log_l1']:.4f} ({x['fit_s']:.0f} s)" for x in points),
                  flush=True)
    return data


def _read(path: Path) -> dict:
    return json.loads(path.read_text()) if path.exists() else {"units": {}}


def _keep(path: Path, key: str, points: list[dict]) -> dict:
    """Adds one unit to the JSON at ``path`` under a lock, so that runs measuring other units (``--sizes``)
    can share the file; returns what the file now holds."""
    import fcntl

    with open(path.with_suffix(".lock"), "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        data = _read(path)
        data["units"][key] = points
        data["machine"] = machine()
        write_json(path, data)
    return data


def _complete(points: list, materials: int) -> list:
    """The points of the (protocol, size, model) cells measured on ``materials`` materials."""
    counts = Counter((p.protocol, p.n_fit, p.contender) for p in points)
    return [p for p in points if counts[p.protocol, p.n_fit, p.contender] == materials]


def section(data: dict, command: str) -> list[str]:
    from neuenh.study.efficiency import CurvePoint
    from neuenh.study.targets import Target, issue23_targets

    points = [CurvePoint(**row) for rows in data["units"].values() for row in rows]
    materials = sorted({p.material for p in points})
    lines = [SECTION, "", f"Command: `{command}`  ", machine_line(data["machine"]) + "  ",
             f"Materials measured: {len(materials)} ({', '.join(m.removesuffix('_rgb') for m in materials)})", "",
             "The report's data-efficiency protocols (`neuenh.study.efficiency`, seed 0, 10,000 test pairs), "
             "medians over the materials; *adaptive*: `--capacity auto` (`neuenh.fit.capacity.Adaptive`), "
             "*latent*: the latent code and analytical parameters alone.", "",
             f"Targets judged on the complete cells only (a model measured at that protocol and size on all "
             f"{len(materials)} materials); the others are in the tables below.", "",
             *Target.HEADER, *(t.markdown() for t in issue23_targets(_complete(points, len(materials))))]
    lines += ["", "Per protocol and fit size, medians over the materials: fit seconds of each model, and the "
              "adaptive fit's parameters per material and chosen capacities.", "",
              "| protocol | samples | materials | latent s | adaptive s | NBRDF s | adaptive params / material "
              "(NBRDF 675) | adaptive capacities |", "|---|---:|---:|---:|---:|---:|---:|---|"]
    cells = sorted({(p.protocol, p.n_fit) for p in points}, key=lambda k: (k[0] != "uniform", k[1]))
    for protocol, n in cells:
        at = [p for p in points if (p.protocol, p.n_fit) == (protocol, n)]
        by = {c: [p for p in at if p.contender == c] for c in EVERY}
        med = lambda c: f"{statistics.median(p.fit_s for p in by[c]):.1f}" if by[c] else "—"  # noqa: E731
        adaptive = by[ENHANCED_ADAPTIVE]
        params = f"{statistics.median(p.params_per_material for p in adaptive):.0f}" if adaptive else "—"
        chosen = ", ".join(f"{c} {k}" for c, k in Counter(p.capacity for p in adaptive).most_common()) or "—"
        lines.append(f"| {protocol} | {n:,} | {len({p.material for p in at})} | {med(ENHANCED)} | "
                     f"{med(ENHANCED_ADAPTIVE)} | {med('nbrdf')} | {params} | {chosen} |")
    lines += ["", "Per material, held-out log-L1 (the adaptive fit's capacity and parameters):", "",
              "| protocol | samples | material | latent | adaptive | GGX | NBRDF |", "|---|---:|---|---:|---:|---:|---:|"]
    for protocol, n in cells:
        for material in materials:
            by = {p.contender: p for p in points if (p.protocol, p.n_fit, p.material) == (protocol, n, material)}
            if not by:
                continue
            cell = lambda c: f"{by[c].heldout_log_l1:.4f}" if c in by else "—"  # noqa: E731
            adaptive = by.get(ENHANCED_ADAPTIVE)
            lines.append(f"| {protocol} | {n:,} | {material.removesuffix('_rgb')} | {cell(ENHANCED)} | "
                         + (f"{adaptive.heldout_log_l1:.4f} ({adaptive.capacity}, {adaptive.params_per_material})"
                            if adaptive else "—") + f" | {cell('ggx')} | {cell('nbrdf')} |")
    return [*lines, ""]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rgl", type=Path, default=ROOT.parent / "shared" / "data" / "rgl")
    parser.add_argument("--model", default="enhanced-ggx", help="the enhanced model (default enhanced-ggx)")
    parser.add_argument("--materials", nargs="+", metavar="NAME", help="only these (file stems)")
    parser.add_argument("--jobs", type=int, default=2, help="units measured at once")
    parser.add_argument("--sizes", type=int, nargs="+", metavar="N", help="only the units of these fit sizes")
    parser.add_argument("--stop-at", metavar="HH:MM", help="start no unit after this time (UTC)")
    parser.add_argument("--json", type=Path, required=True, help="the units measured (read first: resumes)")
    parser.add_argument("--summary", action="store_true", help="measure nothing: summarise --json")
    parser.add_argument("--write", metavar="PATH", help="write/replace this section of PATH (docs/BENCHMARKS.md)")
    args = parser.parse_args(argv)
    if not args.rgl.is_dir():
        print(f"skipped: {args.rgl} is absent (the RGL materials of ../shared)")
        return 0
    data = _read(args.json) if args.summary else run(args)
    if not data.get("units"):
        print("nothing measured yet")
        return 0
    command = " ".join(["python bench/bench_issue23_targets.py",
                        *(a for a in (argv if argv is not None else sys.argv[1:]) if a not in ("--summary",))])
    publish(section(data, command), args.write, SECTION)
    return 0


if __name__ == "__main__":
    sys.exit(main())
