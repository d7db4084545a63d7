"""Issue 23's experiment: does a fit-based score track generalisation where the validation loss does not?

    python bench/bench_selection.py [--model enhanced-ggx] [--extra NAME=BUNDLE ...] [--zoo 14] [--ggx 6]
                                    [--seed 1000] [--protocols uniform mirror] [--workers 2] [--json OUT.json]
                                    [--write docs/BENCHMARKS.md]

Every rung of ``--model`` (each committed round's winner of the search that made it,
``neuenh.pretrained.rungs``), every ``--extra`` bundle and plain GGX are fitted — modules frozen,
per-material parameters free (``neuenh.fit.fit_materials``, default config), the way users use a
model — to materials they never saw, and measured on other samples of the same materials
(``neuenh.study.efficiency.measure_curve``): the visible protocols of docs/RESULTS.md, *uniform*
10,000 fit / 10,000 test pairs and *mirror* 3,000 / 10,000 (half the pairs near the mirror direction).

Materials:

* **held out from the training sources** (what a fit-based selection may look at): ``--zoo``
  synthetic zoo materials and ``--ggx`` noisy synthetic anisotropic GGX materials drawn with seeds
  (``--seed`` + 5 and + 4) that no shipped model's search used (theirs: 5 and 4);
* **the 8 RGL materials** of ``../shared/data/rgl`` (skipped when absent): measured only, never tuned on.

Beside each model its in-sample validation loss (what the search selected by). ``--workers``
processes fit materials in parallel, one torch thread each.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # runnable from a checkout without installing

from bench.harness import machine, machine_line  # noqa: E402
from bench.report import publish  # noqa: E402

SECTION = "## Selection by generalisation: the experiment (issue 23)"
RGL = ROOT.parent / "shared" / "data" / "rgl"
PROTOCOLS = {"uniform": 10_000, "mirror": 3_000}  # protocol -> fit samples (docs/RESULTS.md's visible protocols)
N_TEST = 10_000


def contenders(model: str, extras: dict[str, str]):
    """(name, label, val loss, GraphContender) of every rung of ``model``, every extra bundle, plain GGX."""
    from neuenh.materials import MaterialTable
    from neuenh.models import get_model
    from neuenh.pretrained import load_model, rungs
    from neuenh.study.contenders import GraphContender

    def trained(m, latent):
        return None if latent is None or not m.uses_latent else MaterialTable(
            m.specs, ["mean"], m.latent_dim, latent=latent.reshape(1, -1).float())

    out = []
    for r in rungs(model):
        name = f"{model}@{r.round}:{r.state}"
        out.append((name, r.val_loss, GraphContender(name, name, "enhanced", r.model, trained(r.model, r.latent_mean))))
    for name, path in extras.items():
        m, table = load_model(path)
        from neuenh.checkpoint import Bundle
        val = float(Bundle.load(path).metrics.get("val_loss", float("nan")))
        latent = table.latent.detach().mean(0) if table is not None and len(table) else None
        out.append((f"{name}:{m.state}", val, GraphContender(name, name, "enhanced", m, trained(m, latent))))
    out.append(("ggx", float("nan"), GraphContender("ggx", "GGX", "analytical", get_model("ggx"))))
    return out


def materials(zoo: int, ggx: int, seed: int, rgl: Path):
    """(group, material) of every material measured: held-out synthetic ones, then RGL."""
    from neuenh.data import load_measured
    from neuenh.data.synthetic import synthetic_ggx, synthetic_zoo

    out = [("zoo", m) for m in synthetic_zoo(zoo, seed + 5)] + [("ggx", m) for m in synthetic_ggx(ggx, seed + 4, 0.1)]
    if rgl.is_dir():
        out += [("rgl", load_measured(p)) for p in sorted(rgl.glob("*.bsdf"))]
    return out


_STATE: dict = {}


def _init(args_json: str) -> None:
    import torch

    torch.set_num_threads(1)
    args = json.loads(args_json)
    _STATE["contenders"] = contenders(args["model"], args["extras"])
    _STATE["materials"] = materials(args["zoo"], args["ggx"], args["seed"], Path(args["rgl"]))
    _STATE["cases"] = [(p, PROTOCOLS[p]) for p in args["protocols"]]


def _measure(index: int) -> list[dict]:
    from neuenh.study.efficiency import measure_curve

    group, material = _STATE["materials"][index]
    rows = []
    for protocol, n in _STATE["cases"]:
        start = time.perf_counter()
        points = measure_curve(material, [c for _, _, c in _STATE["contenders"]], sizes=(n,), protocols=(protocol,),
                               n_test=N_TEST, seed=0)
        for p in points:
            rows.append({"group": group, "material": p.material, "protocol": protocol, "n_fit": n,
                         "model": p.contender, "heldout": p.heldout_log_l1, "fit_s": p.fit_s})
        print(f"{group:4s} {material.name:28s} {protocol:8s} {time.perf_counter() - start:6.1f} s  "
              + "  ".join(f"{p.heldout_log_l1:.4f}" for p in points), flush=True)
    return rows


def run(args) -> tuple[list[dict], list[tuple[str, float]]]:
    config = json.dumps({"model": args.model, "extras": dict(e.split("=", 1) for e in args.extra), "zoo": args.zoo,
                         "ggx": args.ggx, "seed": args.seed, "rgl": str(args.rgl), "protocols": args.protocols})
    _init(config)
    names = [(c.name, val) for _, val, c in _STATE["contenders"]]
    labels = {c.name: name for name, _, c in _STATE["contenders"]}
    with ProcessPoolExecutor(args.workers, initializer=_init, initargs=(config,)) as pool:
        rows = [r for part in pool.map(_measure, range(len(_STATE["materials"]))) for r in part]
    for r in rows:
        r["model"] = labels[r["model"]]
    return rows, [(labels[n], v) for n, v in names]


def medians(rows: list[dict], group: str, protocol: str) -> dict[str, float]:
    by: dict[str, list[float]] = {}
    for r in rows:
        if (r["group"] == group or (group == "synthetic" and r["group"] in ("zoo", "ggx"))) and r["protocol"] == protocol:
            by.setdefault(r["model"], []).append(r["heldout"])
    return {m: statistics.median(v) for m, v in by.items()}


def ranks(values: list[float]) -> list[int]:
    order = sorted(range(len(values)), key=lambda i: values[i])
    out = [0] * len(values)
    for rank, i in enumerate(order):
        out[i] = rank
    return out


def spearman(a: list[float], b: list[float]) -> float:
    """Spearman's rank correlation of two equally long lists without ties."""
    ra, rb = ranks(a), ranks(b)
    n = len(a)
    return 1 - 6 * sum((x - y) ** 2 for x, y in zip(ra, rb)) / (n * (n * n - 1))


def markdown_section(env: dict, rows: list[dict], models: list[tuple[str, float]], args, command: str) -> str:
    cases = [(p, PROTOCOLS[p]) for p in args.protocols]
    groups = [g for g in ("zoo", "ggx", "synthetic", "rgl") if g == "synthetic" or any(r["group"] == g for r in rows)]
    counts = {g: len({r["material"] for r in rows if r["group"] == g}) for g in ("zoo", "ggx", "rgl")}
    counts["synthetic"] = counts["zoo"] + counts["ggx"]
    lines = [SECTION, "", f"Command: `{command}`  ", machine_line(env), "",
             "Each model fitted (`fit_materials`, default config, modules frozen) per material and measured on "
             f"{N_TEST:,} other pairs (`neuenh.study.efficiency.measure_curve`, seed 0); medians of the held-out "
             f"log-L1 over the materials. *zoo* ({counts['zoo']}) and *ggx* ({counts['ggx']}): materials of the "
             f"training sources drawn with seeds no search used (synthetic_zoo seed {args.seed + 5}, synthetic_ggx "
             f"seed {args.seed + 4}, noise 0.1); *RGL*: the visible 8, measured, never tuned on. *val*: the "
             "in-sample validation loss the search selected by (held-out samples of its training materials).", ""]
    header = "| model | val | " + " | ".join(f"{g} {p} {n:,}" for p, n in cases for g in groups) + " |"
    lines += [header, "|---|---:|" + "---:|" * (len(cases) * len(groups))]
    table = {(g, p): medians(rows, g, p) for p, _ in cases for g in groups}
    for name, val in models:
        cells = [f"{table[(g, p)].get(name, float('nan')):.4f}" for p, _ in cases for g in groups]
        lines.append(f"| `{name}` | {val:.5f} | " + " | ".join(cells) + " |")
    rungs = [(n, v) for n, v in models if n.startswith(args.model + "@")]
    if len(rungs) >= 3:
        vals = [v for _, v in rungs]
        lines += ["", f"Spearman rank correlation over the {len(rungs)} rungs of `{args.model}` (1 = the same order):", "",
                  "| score | " + " | ".join(f"{g} {p}" for p, _ in cases for g in groups if g != "synthetic") + " |",
                  "|---|" + "---:|" * (len(cases) * (len(groups) - 1))]
        for label, score in [("val (in-sample)", vals)] + [
                (f"fit score, synthetic {p}", [table[("synthetic", p)][n] for n, _ in rungs]) for p, _ in cases]:
            cells = [f"{spearman(score, [table[(g, p)][n] for n, _ in rungs]):+.2f}"
                     for p, _ in cases for g in groups if g != "synthetic"]
            lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--model", default="enhanced-ggx")
    parser.add_argument("--extra", action="append", default=[], help="NAME=BUNDLE_DIR, a further model to measure")
    parser.add_argument("--zoo", type=int, default=14)
    parser.add_argument("--ggx", type=int, default=6)
    parser.add_argument("--seed", type=int, default=1000)
    parser.add_argument("--rgl", type=Path, default=RGL)
    parser.add_argument("--protocols", nargs="+", choices=tuple(PROTOCOLS), default=list(PROTOCOLS))
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--json", type=Path)
    parser.add_argument("--write")
    args = parser.parse_args()
    env = machine()
    rows, models = run(args)
    if args.json:
        args.json.write_text(json.dumps({"rows": rows, "models": models}, indent=1))
    command = "python bench/bench_selection.py " + " ".join(sys.argv[1:])
    publish(markdown_section(env, rows, models, args, command), args.write, SECTION)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
