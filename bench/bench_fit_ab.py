"""A change of a fit protocol's settings against the protocol as it is, beside a null arm, on
training-source materials (issues 23 and 24).

    python bench/bench_fit_ab.py --arm NAME:FIELD=VALUE[,FIELD=VALUE...] [--arm ...] [--capacity auto]
                                 [--model SPEC] [--materials 20] [--fresh SEED | --visible DIR]
                                 [--cases mirror:3000 uniform:10000]
                                 [--test 1000] [--null-seeds 1 [2 ...]] [--arm-seeds] [--json OUT.json]

Every arm fits every material of every case in one process of one torch thread, the arms in an order
rotated from material to material, on the same fit and test samples (``study.heldout.draw_fit_test``,
seed 0; ``mirror:N`` draws half of the pairs near the mirror direction, ``uniform:N`` none):

* **A**: ``FitOptions(capacity=...).protocol_for(model)``, what ``neuenh fit --capacity`` runs, seed 0;
* **null** (and **null2**, **null3**, ... for more ``--null-seeds``): A with another fit seed (its folds'
  shuffles, its low-rank starts, its subsets' draws): the same protocol, so its spread is what rounding
  and seeds alone do to a material's end point — up to ±16 % on single materials, ×1.77 on a plain fit
  (docs/BENCHMARKS.md, "Many materials in one fit", "Stop 73"), which a change must be judged against
  rather than against zero. Per material, its *own spread* is the nulls' largest ratio to A (at least
  1.05); an arm's column "over own spread" is its largest ratio over that bound, with how many
  materials exceed it — the worst material against what the seed alone does to that same material,
  where the plain "worst" compares it with the null's worst over all materials;
* each ``--arm``: A with the protocol's dataclass fields replaced (e.g. ``X:correction_epochs=100``);
  with ``--arm-seeds`` also at every null seed (arms ``NAME@SEED``), and a second table compares, per
  material, the arm's median held-out error over the seeds with A's over the same seeds (A and the nulls):
  a change's typical end point against the protocol's, where a single seed's ratio carries both seed spreads.

Materials: every ``len // N``-th NBRDF stand-in of MERL from the ``--offset``-th (``../shared/data/merl_nbrdf``, sorted names;
never RGL), each fitted with its own training code left out of the model's training codes (the fit's
screened starts would otherwise start where training left it). The shipped modules did see these
materials: a paired comparison of two fits, not a measure of unseen-material error. Every stand-in has
been in some earlier draw, so ``--fresh SEED`` draws new materials of the training sources instead: half
of ``--materials`` of the synthetic zoo (seed SEED + 5) and half noisy synthetic GGX (SEED + 4, noise 0.1),
the families the reference search trained on at seeds 5 and 4 — materials no training and no earlier
rule saw, fitted with every training code; ``--fresh-family zoo`` draws them all from the zoo (for a plain GGX
model, whose fits of noisy GGX end at their rounding floor, held-out ~1e-5, where a ratio of two fits swings
x0.01-x9000 with the seed alone: docs/BENCHMARKS.md, "Stop 73"). ``--visible DIR`` fits the RGL materials of
DIR (the visible 8) instead, for a veto judged like a rule's draw, each material against its own seed spread — a
plain fit's end point on one of them moves 1.6x with the seed (docs/BENCHMARKS.md, "Stop 76"). Recorded per fit:
CPU seconds (``time.process_time``, one thread: what another process on the machine does not add to),
wall seconds, the held-out log-L1 and the capacity and prior chosen. Ratios are per material against A, then the
median, the geometric mean and the worst; an arm's worst is printed beside the null's and against each
material's own spread. The JSON file is
written after every material and resumed by a rerun with the same arguments.
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import json
import math
import re
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # runnable from a checkout without installing

from bench.harness import absent, fitting_process, machine, machine_line, write_json  # noqa: E402

NBRDF_WEIGHTS = ROOT.parent / "shared" / "data" / "merl_nbrdf" / "merl_nbrdf_weights.npz"
NEAR_MIRROR = {"mirror": 0.5, "uniform": 0.0}


def parse_arm(text: str, protocol) -> tuple[str, object]:
    """``NAME:FIELD=VALUE[,FIELD=VALUE...]`` -> (NAME, ``protocol`` with those fields replaced); each
    VALUE a Python literal (or a bare word, read as a string)."""
    name, sep, body = text.partition(":")
    if not sep or not name or not body:
        raise SystemExit(f"--arm {text!r}: write NAME:FIELD=VALUE[,FIELD=VALUE...]")
    if name == "A" or name.startswith("null"):
        raise SystemExit(f"--arm {text!r}: {name} is the bench's own arm's name; name yours otherwise")
    known = {f.name for f in dataclasses.fields(protocol)}
    changes = {}
    for item in re.split(r",(?=\s*[A-Za-z_]\w*=)", body):  # a comma inside a tuple value stays
        key, sep, value = item.partition("=")
        if not sep or key not in known:
            raise SystemExit(f"--arm {text!r}: {key!r} is not a field of {type(protocol).__name__} "
                             f"(its fields: {', '.join(sorted(known))})")
        try:
            changes[key] = ast.literal_eval(value)
        except (ValueError, SyntaxError):
            changes[key] = value
    try:
        return name, dataclasses.replace(protocol, **changes)
    except (TypeError, ValueError) as error:
        raise SystemExit(f"--arm {text!r}: {error}") from None


def parse_case(text: str) -> tuple[float, int]:
    """``mirror:N`` or ``uniform:N`` -> (share of pairs near the mirror, N fitted samples)."""
    kind, _, n = text.partition(":")
    if kind not in NEAR_MIRROR or not n.isdigit() or int(n) < 1:
        raise SystemExit(f"--cases {text!r}: write mirror:N or uniform:N (N fitted samples)")
    return NEAR_MIRROR[kind], int(n)


SPREAD_FLOOR = 1.05  # a material's own spread is never taken below +5 %


def null_arms(seeds: list[int]) -> list[str]:
    """The null arms' names, one per seed: null, null2, null3, ..."""
    return ["null" if i == 0 else f"null{i + 1}" for i in range(len(seeds))]


def summary(results: dict, case: str, arm: str) -> dict | None:
    """``arm`` against A over ``case``'s materials: median CPU ratio, held-out median, geometric mean,
    worst and best ratio, on how many materials it is lower, and — for an arm that is not a null — its
    largest ratio over each material's own spread and on how many it exceeds it (module doc); None
    before any material is done."""
    rows = [r for key, r in results["fits"].items() if key.split("|")[0] == case]
    if not rows:
        return None
    ratio = lambda r, a: r[a]["loss"] / r["A"]["loss"]
    cpu = [r[arm]["cpu"] / r["A"]["cpu"] for r in rows]
    held = [ratio(r, arm) for r in rows]
    out = {"materials": len(rows), "cpu": statistics.median(cpu), "median": statistics.median(held),
           "geo": math.exp(statistics.fmean(math.log(h) for h in held)), "worst": max(held), "best": min(held),
           "lower": sum(h < 1 for h in held), "over_spread": None, "above_spread": None}
    if not arm.startswith("null"):
        nulls = [a for a in results["arms"] if a.startswith("null")]
        over = [ratio(r, arm) / max(SPREAD_FLOOR, *(ratio(r, n) for n in nulls)) for r in rows]
        out.update(over_spread=max(over), above_spread=sum(o > 1 for o in over))
    return out


def seed_median_summary(results: dict, case: str, arm: str) -> dict | None:
    """Per material of ``case``, the median held-out error of ``arm`` over its seeds (``arm`` and every
    ``arm@SEED``) over A's median over the same seeds (A and the nulls): the median, geometric mean,
    worst and best of those ratios, and on how many materials it is below 1; None before any material."""
    rows = [r for key, r in results["fits"].items() if key.split("|")[0] == case]
    if not rows:
        return None
    mine = [arm, *(a for a in results["arms"] if a.startswith(arm + "@"))]
    theirs = ["A", *(a for a in results["arms"] if a.startswith("null"))]
    held = [statistics.median(r[a]["loss"] for a in mine) / statistics.median(r[a]["loss"] for a in theirs)
            for r in rows]
    return {"materials": len(rows), "seeds": len(mine), "median": statistics.median(held),
            "geo": math.exp(statistics.fmean(math.log(h) for h in held)), "worst": max(held), "best": min(held),
            "lower": sum(h < 1 for h in held)}


def markdown(results: dict, command: str) -> str:
    lines = [f"Command: `{command}`  ", machine_line(results["machine"]) + "  ",
             f"Model: {results['config']['model']}, capacity `{results['config']['capacity']}`; arms: "
             + "; ".join(f"**{name}** {what}" for name, what in results["arms"].items()), "",
             "| case | arm / A | materials | CPU, median ratio | held-out: median | geometric mean | worst | best | lower on "
             "| over own spread (materials above) |",
             "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for case in results["config"]["cases"]:
        for arm in (a for a in results["arms"] if a != "A" and "@" not in a):
            s = summary(results, case, arm)
            if s is not None:
                spread = "—" if s["over_spread"] is None else f"{s['over_spread']:.3f} ({s['above_spread']})"
                lines.append(f"| {case} | {arm} | {s['materials']} | {s['cpu']:.3f} | {s['median']:.4f} | {s['geo']:.4f} | "
                             f"{s['worst']:.3f} | {s['best']:.3f} | {s['lower']} | {spread} |")
    seeded = [a for a in results["arms"] if any(b.startswith(a + "@") for b in results["arms"])]
    if seeded:
        lines += ["", "Per material, the arm's median held-out error over its seeds / A's over the same seeds:", "",
                  "| case | arm / A | materials | seeds | median | geometric mean | worst | best | lower on |",
                  "|---|---|---:|---:|---:|---:|---:|---:|---:|"]
        for case in results["config"]["cases"]:
            for arm in seeded:
                s = seed_median_summary(results, case, arm)
                if s is not None:
                    lines.append(f"| {case} | {arm} | {s['materials']} | {s['seeds']} | {s['median']:.4f} | "
                                 f"{s['geo']:.4f} | {s['worst']:.3f} | {s['best']:.3f} | {s['lower']} |")
    return "\n".join(lines) + "\n"


def draw_materials(args, trained) -> tuple[dict, dict]:
    """{key: material}, {key: the training codes its fits start from}: the
    stand-ins of the ``--offset`` draw, each without its own code, or ``--fresh``'s new materials with
    every code (module doc)."""
    import numpy as np

    if args.visible is not None:
        from neuenh.data import load_measured

        drawn = {path.stem: load_measured(path) for path in sorted(args.visible.glob("*.bsdf"))}
        if not drawn:
            raise SystemExit(f"--visible {args.visible}: no .bsdf files there")
        return drawn, dict.fromkeys(drawn, trained)
    if args.fresh is not None:
        from neuenh.data.synthetic import synthetic_ggx, synthetic_zoo

        n_ggx = 0 if args.fresh_family == "zoo" else args.materials // 2
        zoo = synthetic_zoo(args.materials - n_ggx, args.fresh + 5)
        ggx = synthetic_ggx(n_ggx, args.fresh + 4, 0.1) if n_ggx else []
        drawn = {f"{family}{args.fresh}/{m.name}": m for family, ms in (("zoo", zoo), ("ggx", ggx)) for m in ms}
        return drawn, dict.fromkeys(drawn, trained)
    from neuenh.data.nbrdf import nbrdf_material

    names = sorted(np.load(args.nbrdf)["names"].tolist())
    step = max(1, len(names) // args.materials)
    if not 0 <= args.offset < step:
        raise SystemExit(f"--offset {args.offset}: must be in 0 .. {step - 1} (every {step}th of {len(names)} names)")
    chosen = names[args.offset :: step][: args.materials]
    # each material's fits start from the training codes of every other (the same for every case)
    codes_of = {name: None if trained is None else trained.subset([i for i, t in enumerate(trained.names) if t != name])
                for name in chosen}
    return {name: nbrdf_material(str(args.nbrdf), name) for name in chosen}, codes_of


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--arm", action="append", default=[], metavar="NAME:FIELD=VALUE,...",
                        help="a variant of the protocol (repeatable)")
    parser.add_argument("--capacity", default="auto", help="the protocol: neuenh fit's --capacity (default auto)")
    parser.add_argument("--model", default="enhanced-ggx", help="the enhanced model (default enhanced-ggx)")
    parser.add_argument("--materials", type=int, default=20, help="how many NBRDF stand-ins (default 20)")
    parser.add_argument("--offset", type=int, default=0,
                        help="start the every-len//N-th draw of stand-ins at this name (default 0; another draw of "
                             "the same size: 1 .. len//N - 1)")
    parser.add_argument("--fresh", type=int, metavar="SEED",
                        help="draw new synthetic materials of the training sources at this seed instead of stand-ins")
    parser.add_argument("--fresh-family", choices=("both", "zoo"), default="both",
                        help="--fresh's materials: half zoo and half noisy GGX (default), or all zoo")
    parser.add_argument("--visible", type=Path, metavar="DIR",
                        help="fit the RGL materials of DIR instead (the visible 8, ../shared/data/rgl): a veto's "
                             "materials, never a rule's draw")
    parser.add_argument("--cases", nargs="+", default=["mirror:3000", "uniform:10000"])
    parser.add_argument("--test", type=int, default=1000, help="test pairs per material (default 1,000)")
    parser.add_argument("--null-seeds", type=int, nargs="+", default=[1],
                        help="the null arms' fit seeds, one arm each (default 1; A's is 0)")
    parser.add_argument("--arm-seeds", action="store_true",
                        help="fit every --arm at every null seed too, and compare seed medians (module doc)")
    parser.add_argument("--nbrdf", type=Path, default=NBRDF_WEIGHTS)
    parser.add_argument("--json", type=Path, help="write (and resume) the raw numbers here")
    args = parser.parse_args(argv)
    if args.fresh is not None and args.visible is not None:
        raise SystemExit("--fresh and --visible: choose one draw")
    if args.visible is not None and absent(args.visible, "the RGL materials of ../shared"):
        return 0
    if args.fresh is None and args.visible is None and absent(args.nbrdf, "the NBRDF stand-ins of MERL"):
        return 0
    cases = {case: parse_case(case) for case in args.cases}
    fitting_process()  # one torch thread and one Dr.Jit thread
    from neuenh.fit import FitOptions, fit_materials
    from neuenh.pretrained import load_model
    from neuenh.study.heldout import draw_fit_test, heldout_log_l1

    model, trained = load_model(args.model)
    try:
        base = FitOptions(capacity=args.capacity).protocol_for(model)
    except ValueError as error:
        raise SystemExit(f"--capacity {args.capacity!r}: {error}") from None
    variants = [(text, *parse_arm(text, base)) for text in args.arm]
    if len({name for _, name, _ in variants}) < len(variants):
        raise SystemExit(f"--arm: two arms share a name ({', '.join(args.arm)})")
    if 0 in args.null_seeds or len(set(args.null_seeds)) < len(args.null_seeds):
        raise SystemExit(f"--null-seeds {args.null_seeds}: distinct seeds other than A's 0")
    nulls = dict(zip(null_arms(args.null_seeds), args.null_seeds))
    arms = {"A": (base, 0), **{name: (base, seed) for name, seed in nulls.items()},
            **{name: (protocol, 0) for _, name, protocol in variants},
            **{f"{name}@{seed}": (protocol, seed) for _, name, protocol in variants if args.arm_seeds
               for seed in args.null_seeds}}
    config = {"model": args.model, "capacity": args.capacity, "materials": args.materials, "offset": args.offset,
              "fresh": args.fresh, "fresh_family": args.fresh_family, "visible": args.visible and str(args.visible),
              "cases": args.cases, "test": args.test,
              "null_seeds": args.null_seeds, "arms": args.arm, "arm_seeds": args.arm_seeds}
    results = json.loads(args.json.read_text()) if args.json and args.json.exists() else {}
    if results.get("config") != config:
        results = {"config": config, "fits": {}}
    results["machine"] = machine()
    results["arms"] = {"A": f"`{base}`", **{name: f"A, fit seed {seed}" for name, seed in nulls.items()},
                       **{name: text.split(":", 1)[1] for text, name, _ in variants},
                       **{f"{name}@{seed}": f"{name}, fit seed {seed}" for _, name, _ in variants if args.arm_seeds
                          for seed in args.null_seeds}}
    materials, codes_of = draw_materials(args, trained)
    for case, (near_mirror, n) in cases.items():
        for index, (name, material) in enumerate(materials.items()):
            key = f"{case}|{name}"
            if key in results["fits"]:
                continue
            fit, test, _ = draw_fit_test(material, n, args.test, 0, near_mirror)
            order = list(arms)[index % len(arms):] + list(arms)[: index % len(arms)]
            row = {}
            for arm in order:
                protocol, seed = arms[arm]
                cpu, wall = time.process_time(), time.perf_counter()
                result = fit_materials(model, fit, protocol, trained=codes_of[name], seed=seed)
                row[arm] = {"cpu": time.process_time() - cpu, "wall": time.perf_counter() - wall,
                            "loss": heldout_log_l1(model, result, test)[0], "capacity": result.capacity(0),
                            "prior": (result.details[0] if result.details else {}).get("prior")}
            results["fits"][key] = row
            if args.json:
                write_json(args.json, results)
            print(f"{time.strftime('%H:%M:%S')} {key:40s} " + "  ".join(
                f"{arm} {row[arm]['cpu']:5.1f} s {row[arm]['loss']:.5f} {row[arm]['capacity']}" for arm in arms),
                flush=True)
    print()
    print(markdown(results, "python bench/bench_fit_ab.py " + " ".join(sys.argv[1:] if argv is None else argv)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
