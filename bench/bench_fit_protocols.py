"""Fit time and held-out error of every fit protocol beside NBRDF's fit, on training-source
materials (issues 23 and 24), and the previous default fit of ``--before-rev`` in the same run.

    python bench/bench_fit_protocols.py [--model SPEC] [--before-rev REV] [--materials N] [--sizes 3000 10000]
                                        [--json OUT.json] [--write docs/BENCHMARKS.md]

Materials: ``--materials`` NBRDF stand-ins of MERL (``../shared/data/merl_nbrdf``, a training source;
every 12th name in sorted order — the shipped modules may have seen them; never RGL). Per material
and fit size, the fit and test sets of the study (``neuenh.study.heldout.draw_fit_test``, seed 0,
half the pairs near the mirror direction, 10,000 test pairs drawn the same way), one torch thread:

* **default**: ``fit_materials(model, fit)`` with the checkout's default protocol — in the checkout
  ``--before-rev`` names too (``git archive`` to a temporary folder, this file run there first);
* **adaptive** (this checkout): ``FitOptions(capacity="auto")``, the capacity chosen per material
  by cross-validation;
* **NBRDF**: ``NBRDFContender`` (a 6-21-21-3 network per material, its defaults);

each for the enhanced model (``--model``) and plain GGX (default only). Recorded: the wall time of
the fit and the held-out log-L1 (``train.log_l1`` on the test set). Ratios are per material first,
then the median over materials.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # runnable from a checkout without installing

from bench.harness import fitting_process, machine, machine_line, run_at_revision, wait_quiet, write_json  # noqa: E402
from bench.report import publish  # noqa: E402

SECTION = "## Fit protocols against NBRDF (issues 23, 24)"
NBRDF_WEIGHTS = ROOT.parent / "shared" / "data" / "merl_nbrdf" / "merl_nbrdf_weights.npz"
N_TEST = 10_000
NEAR_MIRROR = 0.5


def materials(count: int, weights: Path) -> list:
    import numpy as np

    from neuenh.data.nbrdf import nbrdf_material

    names = sorted(np.load(weights)["names"].tolist())
    return [nbrdf_material(str(weights), name) for name in names[::12][:count]]


def run(spec: str, weights: Path, count: int, sizes: list[int], default_only: bool, clock=time.perf_counter) -> dict:
    """{case: {material: (held-out log-L1, seconds of ``clock``)}}."""
    from neuenh.fit import fit_materials
    from neuenh.models import get_model
    from neuenh.pretrained import load_model
    from neuenh.study.heldout import draw_fit_test, heldout_log_l1
    from neuenh.train import log_l1

    enhanced, trained = load_model(spec)
    models = {"enhanced": (enhanced, trained), "GGX": (get_model("ggx"), None)}
    out: dict = {}

    def record(case: str, name: str, heldout: float, seconds: float) -> None:
        out.setdefault(case, {})[name] = (heldout, seconds)
        print(f"{case:28s} {name:24s} held-out {heldout:.5f} {seconds:6.2f} s", flush=True)

    for material in materials(count, weights):
        for n in sizes:
            fit, test, _ = draw_fit_test(material, n, N_TEST, 0, near_mirror=NEAR_MIRROR)
            for label, (model, table) in models.items():
                start = clock()
                result = fit_materials(model, fit, seed=0, trained=table)
                seconds = clock() - start
                record(f"{label} default, {n}", material.name, heldout_log_l1(model, result.materials, test)[0], seconds)
            if default_only:
                continue
            from neuenh.fit import FitOptions
            from neuenh.study.contenders import NBRDFContender

            start = clock()
            result = fit_materials(enhanced, fit, FitOptions(capacity="auto").protocol_for(enhanced), seed=0,
                                   trained=trained)
            seconds = clock() - start
            record(f"enhanced adaptive, {n}", material.name, heldout_log_l1(enhanced, result, test)[0], seconds)
            print("   capacity", result.capacity(0), flush=True)
            start = clock()
            fitted = NBRDFContender().fit(fit)
            seconds = clock() - start
            heldout = float(log_l1(fitted.predict(test.wi, test.wo), test.f_r, test.wi).double().mean())
            record(f"NBRDF, {n}", material.name, heldout, seconds)
    return out


def run_before(rev: str, args: argparse.Namespace) -> dict:
    """This file's ``run`` (default fits only) in the repository at ``rev``."""
    return run_at_revision(rev, Path(__file__), ["--model", str(args.model), "--materials", str(args.materials),
                                                 "--nbrdf", str(args.nbrdf.resolve()), "--sizes", *map(str, args.sizes),
                                                 "--default-only"])


def markdown_section(env: dict, now: dict, before: dict | None, command: str, model: str, sizes: list[int],
                     clock: str = "wall") -> str:
    lines = [SECTION, "", f"Command: `{command}`  ", machine_line(env) + "  ", f"Enhanced model: {model}", "",
             f"Per material the fit's {'CPU' if clock == 'cpu' else 'wall'} time and held-out log-L1 (10,000 test pairs, half near the mirror); "
             "*ratios* per material against NBRDF's fit of the same samples in the same run, then the median "
             "(worst in brackets). *before*: the default fit of the checkout `--before-rev` names, run first.",
             "", "| fit | samples | median s | time / NBRDF | median held-out | held-out / NBRDF | held-out / before |",
             "|---|---:|---:|---:|---:|---:|---:|"]
    for n in sizes:
        nbrdf = now[f"NBRDF, {n}"]
        for label, table in [(f"{c} (before)", before.get(f"{c}, {n}") if before else None)
                             for c in ("enhanced default", "GGX default")] + \
                            [(c, now[f"{c}, {n}"]) for c in ("enhanced default", "enhanced adaptive", "GGX default",
                                                            "NBRDF")]:
            if not table:
                continue
            base = label.removesuffix(" (before)")
            old = before.get(f"{base}, {n}") if before and not label.endswith("(before)") else None
            time_ratio = [table[m][1] / nbrdf[m][1] for m in table]
            err_ratio = [table[m][0] / nbrdf[m][0] for m in table]
            vs_before = f"{statistics.median(table[m][0] / old[m][0] for m in table):.3f} " \
                        f"[{max(table[m][0] / old[m][0] for m in table):.3f}]" if old else "—"
            lines.append(f"| {label} | {n:,} | {statistics.median(t for _, t in table.values()):.2f} | "
                         f"{statistics.median(time_ratio):.2f} [{max(time_ratio):.2f}] | "
                         f"{statistics.median(e for e, _ in table.values()):.4f} | "
                         f"{statistics.median(err_ratio):.2f} [{max(err_ratio):.2f}] | {vs_before} |")
    lines += ["", "Per material, held-out log-L1 (seconds):", "",
              "| case | " + " | ".join(next(iter(now.values()))) + " |", "|---|" + "---:|" * len(next(iter(now.values())))]
    for case, table in [*(((f"before: {c}", t) for c, t in before.items()) if before else ()), *now.items()]:
        lines.append(f"| {case} | " + " | ".join(f"{e:.4f} ({s:.1f})" for e, s in table.values()) + " |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", default="enhanced-ggx", help="the enhanced model (default enhanced-ggx)")
    parser.add_argument("--before-rev", metavar="REV", help="also run this revision's default fit first")
    parser.add_argument("--materials", type=int, default=6, help="how many NBRDF stand-ins (default 6)")
    parser.add_argument("--sizes", type=int, nargs="+", default=[3000, 10000], help="fit sizes")
    parser.add_argument("--nbrdf", type=Path, default=NBRDF_WEIGHTS, help=f"the NBRDF weights (default {NBRDF_WEIGHTS})")
    parser.add_argument("--default-only", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--json", type=Path, help="write the raw numbers here")
    parser.add_argument("--write", metavar="PATH", help="write/replace this section of PATH (docs/BENCHMARKS.md)")
    parser.add_argument("--max-wait", type=float, default=300.0)
    parser.add_argument("--clock", choices=("wall", "cpu"), default="wall",
                        help="time fits by wall clock (default) or by this process's CPU time (one torch thread: "
                             "steadier than wall time when other processes share the cores)")
    args = parser.parse_args(argv)
    if not args.nbrdf.is_file():
        print(f"skipped: {args.nbrdf} is absent (the NBRDF stand-ins of ../shared)")
        return 0
    if Path(args.model).is_dir():
        args.model = str(Path(args.model).resolve())  # the older checkout runs elsewhere
    fitting_process()
    wait_quiet(args.max_wait, 0.3)
    env = machine()
    before = run_before(args.before_rev, args) if args.before_rev else None
    now = run(args.model, args.nbrdf, args.materials, args.sizes, args.default_only,
              time.process_time if args.clock == "cpu" else time.perf_counter)
    if args.json:
        write_json(args.json, {"now": now, "before": before} if not args.default_only else now)
    if args.default_only:
        return 0
    from neuenh.pretrained import load_model

    enhanced, _ = load_model(args.model)
    name = Path(args.model).name if Path(args.model).is_dir() else args.model
    model = f"{name}, state {enhanced.state}, {sum(p.numel() for p in enhanced.parameters()):,} weights"
    command = " ".join(["python bench/bench_fit_protocols.py", *(argv if argv is not None else sys.argv[1:])])
    publish(markdown_section(env, now, before, command, model, args.sizes, args.clock).splitlines(), args.write, SECTION)
    return 0


if __name__ == "__main__":
    sys.exit(main())
