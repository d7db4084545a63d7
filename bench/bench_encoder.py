"""Amortised starts (issue 24): the encoder alone against today's fit, and fits started from it.

    python bench/bench_encoder.py [--model SPEC] [--rgl DIR] [--n-fit 3000] [--n-test 10000]
                                  [--near-mirror 0.5] [--json OUT.json] [--write docs/BENCHMARKS.md]

``--model`` is a bundle with an encoder (``neuenh encoder train``). Materials: the training sources'
materials the encoder was *not* trained on (its record's ``heldout_materials``; the shared modules
may have seen them) and the RGL materials of ``--rgl`` (measured, never tuned on). Per material the
fit and test sets of the study (``neuenh.study.heldout.draw_fit_test``, seed 0, ``--near-mirror`` of
the pairs near the mirror direction: 0.5 is the README's protocol), one torch thread, and:

* **encoder alone**: the encoder's parameters from the fit set, no fitting; held-out log-L1;
* **today**: ``fit_materials`` with ``LatentAdam()`` from its own starts, without the encoder's (which
  ``neuenh fit`` adds as one more start: docs/BENCHMARKS.md, "The encoder as a start"; its analytical and imitation starts,
  300 Adam epochs); held-out log-L1, fit loss and wall time;
* **from the encoder, E epochs**: one start, the encoder's, ``LatentAdam(epochs=E).fit(..., start=...)``;
* **epochs to today's loss**: the shortest of the E above whose fit loss is at most today's final
  fit loss (none: neither);
* **spread of end points**: the fit loss of each start fitted alone for 300 epochs — today's kinds of
  start (the paper's, the training materials' mean latent code) and the encoder's from three random
  halves of the fit set — as (max - min) / min over the starts of each kind.

Figures are medians over the materials of each group; ratios are taken per material first.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # runnable from a checkout without installing

import torch  # noqa: E402

from bench.harness import fitting_process, machine, machine_line, wait_quiet  # noqa: E402
from bench.report import publish  # noqa: E402
from neuenh.files import atomic_write  # noqa: E402

SECTION = "## Amortised starts (issue 24)"
RGL = ROOT.parent / "shared" / "data" / "rgl"
SHORT = (30, 100)  # epochs of the fits from the encoder's start
FULL = 300  # today's fast fit


def heldout_materials(record: dict) -> list:
    """The training sources' materials the encoder was held out from, from its training record."""
    from pydantic import TypeAdapter

    from neuenh.data.sources import DataSource

    wanted = set(record.get("heldout_materials") or ())
    out = []
    for raw in record.get("sources") or ():
        source = TypeAdapter(DataSource).validate_python(raw)
        if hasattr(source, "load_materials"):
            out += [m for m in source.load_materials() if m.name in wanted]
    return out


def measure(model, trained, encoder, material, n_fit: int, n_test: int, near_mirror: float) -> dict:
    from neuenh.fit import LatentAdam, fit_materials
    from neuenh.materials import MaterialTable
    from neuenh.study.heldout import draw_fit_test, heldout_log_l1

    fit, test, _ = draw_fit_test(material, n_fit, n_test, 0, near_mirror=near_mirror)
    row: dict = {"material": material.name}
    start = time.perf_counter()
    encoded = encoder.encode(fit)
    row["encoder_s"] = time.perf_counter() - start
    (row["encoder_alone"],) = heldout_log_l1(model, encoded, test)
    today = fit_materials(model, fit, LatentAdam(), trained=trained)
    (row["today"],) = heldout_log_l1(model, today.materials, test)
    row["today_fit_loss"], row["today_s"] = today.losses[0], today.wall_s
    for epochs in SHORT:
        result = LatentAdam(epochs=epochs).fit(model, fit, start=encoder.encode(fit))
        (row[f"encoder+{epochs}"],) = heldout_log_l1(model, result.materials, test)
        row[f"encoder+{epochs}_fit_loss"], row[f"encoder+{epochs}_s"] = result.losses[0], result.wall_s
    reached = [epochs for epochs in SHORT if row[f"encoder+{epochs}_fit_loss"] <= today.losses[0]]
    row["epochs_to_today"] = reached[0] if reached else None  # the shortest of SHORT that reached it
    row["encoder+300_fit_loss"] = LatentAdam(epochs=FULL).fit(model, fit, start=encoder.encode(fit)).losses[0]
    # the spread of end points: each start fitted alone (stacked rows of one run)
    paper = MaterialTable(model.specs, fit.names, model.latent_dim)
    starts = [paper]
    if trained is not None and model.uses_latent:
        mean = MaterialTable(model.specs, fit.names, model.latent_dim, {k: v.detach() for k, v in paper.raw.items()},
                             trained.latent.detach().mean(0, keepdim=True))
        starts.append(mean)
    g = torch.Generator().manual_seed(1)
    halves = [encoder.encode(fit.subset(torch.randperm(len(fit), generator=g)[: len(fit) // 2])) for _ in range(3)]
    ends = [LatentAdam(epochs=FULL).fit(model, fit, start=s).losses[0] for s in starts + halves]
    today_ends, encoder_ends = ends[: len(starts)], ends[len(starts):]
    row["spread_today_starts"] = (max(today_ends) - min(today_ends)) / min(today_ends)
    row["spread_encoder_starts"] = (max(encoder_ends) - min(encoder_ends)) / min(encoder_ends)
    print(json.dumps({k: round(v, 5) if isinstance(v, float) else v for k, v in row.items()}), flush=True)
    return row


def summary(rows: list[dict]) -> dict:
    med = lambda key: statistics.median(r[key] for r in rows)  # noqa: E731
    reached = [r["epochs_to_today"] for r in rows if r["epochs_to_today"] is not None]
    out = {"materials": len(rows), "encoder_alone": med("encoder_alone"), "today": med("today"),
           "alone_over_today": statistics.median(r["encoder_alone"] / r["today"] for r in rows),
           "today_s": med("today_s"), "encoder_s": med("encoder_s"),
           "reached_today": f"{len(reached)}/{len(rows)}",
           "epochs_to_today": statistics.median(reached) if reached else None,
           "spread_today_starts": med("spread_today_starts"), "spread_encoder_starts": med("spread_encoder_starts")}
    for epochs in SHORT:
        key = f"encoder+{epochs}"
        out[key] = med(key)
        out[f"{key}_over_today"] = statistics.median(r[key] / r["today"] for r in rows)
        out[f"{key}_worst_over_today"] = max(r[key] / r["today"] for r in rows)
        out[f"{key}_time_over_today"] = statistics.median(r[f"{key}_s"] / r["today_s"] for r in rows)
    return out


def markdown_section(env: dict, groups: dict[str, list[dict]], command: str, model: str, n_fit: int,
                     near_mirror: float) -> str:
    lines = [SECTION, "", f"Command: `{command}`  ", machine_line(env) + "  ", f"Model: {model}", "",
             f"Fit sets of {n_fit:,} measurements ({near_mirror:.0%} near the mirror direction), held-out "
             "log-L1 on independent test sets; medians over each group's materials, ratios per material first "
             "(`bench/bench_encoder.py` says what each column is). *Today*: the latent fit from its own starts, without "
             "the encoder's (which `neuenh fit` adds as one more: \"The encoder as a start\").", "",
             "| materials | n | encoder alone | today | alone / today | "
             + " | ".join(f"encoder + {e} epochs / today (worst)" for e in SHORT)
             + " | time of encoder + 100 / today | epochs from the encoder to today's fit loss (reached) "
               "| end-point spread: today's starts / encoder's starts |",
             "|---|---:|---:|---:|---:|" + "---:|" * len(SHORT) + "---:|---:|---:|"]
    for label, rows in groups.items():
        if not rows:
            continue
        s = summary(rows)
        epochs = f"{s['epochs_to_today']:.0f}" if s["epochs_to_today"] is not None else "never"
        lines.append(f"| {label} | {s['materials']} | {s['encoder_alone']:.4f} | {s['today']:.4f} | "
                     f"{s['alone_over_today']:.2f}× | "
                     + " | ".join(f"{s[f'encoder+{e}_over_today']:.3f} ({s[f'encoder+{e}_worst_over_today']:.2f})"
                                  for e in SHORT)
                     + f" | {s['encoder+100_time_over_today']:.2f}× | {epochs} ({s['reached_today']}) | "
                       f"{100 * s['spread_today_starts']:.1f} % / {100 * s['spread_encoder_starts']:.1f} % |")
    lines += ["", "Per material (held-out log-L1: encoder alone → encoder + 100 epochs; today):", "",
              "| material | encoder alone | encoder + 100 | today |", "|---|---:|---:|---:|"]
    for rows in groups.values():
        lines += [f"| {r['material']} | {r['encoder_alone']:.4f} | {r['encoder+100']:.4f} | {r['today']:.4f} |"
                  for r in rows]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", default="enhanced-ggx", help="a bundle with an encoder (default enhanced-ggx)")
    parser.add_argument("--rgl", type=Path, default=RGL, help=f"the RGL materials (default {RGL})")
    parser.add_argument("--n-fit", type=int, default=3000)
    parser.add_argument("--n-test", type=int, default=10_000)
    parser.add_argument("--near-mirror", type=float, default=0.5)
    parser.add_argument("--limit", type=int, default=None, help="at most this many held-out training materials")
    parser.add_argument("--json", type=Path, help="write the raw numbers here")
    parser.add_argument("--write", metavar="PATH", help="write/replace this section of PATH (docs/BENCHMARKS.md)")
    parser.add_argument("--max-wait", type=float, default=300.0)
    args = parser.parse_args(argv)
    from neuenh.checkpoint import Bundle
    from neuenh.data import load_measured
    from neuenh.pretrained import bundle_path

    path = bundle_path(args.model)
    if path is None:
        parser.error(f"--model {args.model}: neither a bundle folder nor a shipped model")
    bundle = Bundle.load(path)
    if bundle.encoder is None:
        parser.error(f"--model {args.model}: the bundle has no encoder (neuenh encoder train)")
    fitting_process()
    wait_quiet(args.max_wait, 0.3)
    env = machine()
    held = heldout_materials(bundle.encoder.record)[: args.limit]
    rgl = [load_measured(p) for p in sorted(args.rgl.glob("*.bsdf"))] if args.rgl.is_dir() else []
    if not rgl:
        print(f"no RGL materials in {args.rgl}: measuring the training sources' held-out materials only")
    groups = {}
    for label, materials in (("training sources, held out from the encoder", held), ("RGL, visible 8", rgl)):
        groups[label] = [measure(bundle.model, bundle.materials, bundle.encoder, m, args.n_fit, args.n_test,
                                 args.near_mirror) for m in materials]
    if args.json:
        atomic_write(args.json, json.dumps(groups, indent=1))
    command = " ".join(["python bench/bench_encoder.py", *(argv if argv is not None else sys.argv[1:])])
    model = f"{path.name}, state {bundle.model.state}, encoder of {bundle.encoder.describe()['n_weights']:,} weights"
    publish(markdown_section(env, groups, command, model, args.n_fit, args.near_mirror), args.write, SECTION)
    return 0


if __name__ == "__main__":
    sys.exit(main())
