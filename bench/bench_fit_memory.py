#!/usr/bin/env python
"""A fit's memory and time with its materials in blocks (``neuenh.fit.run``) or in one batch.

    .venv/bin/python bench/bench_fit_memory.py                              # print the numbers (~15 min)
    .venv/bin/python bench/bench_fit_memory.py --write docs/BENCHMARKS.md   # also record them

Each case runs ``fit_materials`` with the shipped ``enhanced-ggx`` (its training codes as starts) on
zoo materials (``synthetic_zoo``, seed 11; the fit's cost per sample does not depend on the material)
in a fresh process of one torch thread as ``neuenh fit`` runs (``bench.harness.fitting_process``),
once with the protocol's own ``block_samples`` and once with every material in one batch, and records the
process's peak RSS over its RSS before the fit (``VmHWM``, ``VmRSS``) and the fit's wall time.

1. *Memory*: 64 materials of 10,000 samples, the adaptive (``auto``) and latent fits at budgets cut
   to a few epochs — a step's memory does not depend on how many steps there are.
2. *Mixed sizes*: 20 materials of 2,000 samples and one of 60,000 (100,000 samples, but 1.26 M slots
   once every material is padded to the largest), the adaptive fit at the short budgets.
3. *Time*: 40 materials of 3,000 samples (blocks of 13, 13, 13 and 1), the latent fit at its default budget:
   what the blocks cost where one batch still fits in memory.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # runnable from a checkout without installing

from bench.harness import machine, machine_line, output_arguments, wait_quiet, write_json  # noqa: E402
from bench.report import publish  # noqa: E402

SECTION = "## A fit's memory, bounded by blocks of materials (stops 57, 58)"
ONE_BATCH = 10**12  # block_samples that holds any fit: every material in one batch
CASES = [  # (what, materials, samples per material (a list: one count each), capacity, short budget)
    ("memory", 64, 10_000, "auto", True),
    ("memory", 64, 10_000, "latent", True),
    ("mixed sizes", 21, [2_000] * 20 + [60_000], "auto", True),
    ("time", 40, 3_000, "latent", False),
]


def child(materials: int, samples: int | list[int], capacity: str, short: bool, block_samples: int | None) -> dict:
    """One fit in this (fresh) process: its peak RSS over the RSS before it, and its wall time."""
    from bench.harness import fitting_process, status_bytes

    fitting_process()
    from neuenh.data.samples import Samples, sample_materials
    from neuenh.data.synthetic import synthetic_zoo
    from neuenh.fit import Adaptive, FitOptions, LatentAdam, fit_materials
    from neuenh.pretrained import load_model

    model, trained = load_model("enhanced-ggx")
    counts = samples if isinstance(samples, list) else [samples] * materials
    zoo = synthetic_zoo(materials, seed=11)
    data = Samples.concat([sample_materials([zoo[i]], n, seed=i) for i, n in enumerate(counts)])
    if short:
        protocol = (Adaptive(latent_epochs=4, correction_epochs=4, lbfgs_iterations=4) if capacity == "auto"
                    else LatentAdam(epochs=8))
    else:
        protocol = FitOptions(capacity=capacity).protocol_for(model)
    before = status_bytes("VmRSS")
    start = time.perf_counter()
    result = fit_materials(model, data, protocol, trained=trained, block_samples=block_samples)
    return {"seconds": time.perf_counter() - start, "before_bytes": before,
            "peak_bytes": status_bytes("VmHWM"), "blocks": result.protocol.get("blocks", 1),
            "loss": result.loss}


def measure(materials: int, samples: int, capacity: str, short: bool, block_samples: int | None) -> dict:
    out = subprocess.run([sys.executable, __file__, "--child", json.dumps([materials, samples, capacity, short,
                                                                           block_samples])],
                         capture_output=True, text=True, check=False, cwd=ROOT)
    if out.returncode != 0:
        raise RuntimeError(f"the fit's child failed:\n{out.stderr}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def _gib(n: float) -> str:
    return f"{n / 2**30:.2f} GiB"


def markdown_section(env: dict, waited: float, rows: list[dict], command: str) -> list[str]:
    lines = [SECTION, "", f"Command: `{command}`  ", f"Date: {env['date']}  ", machine_line(env) + "  ",
             f"Waited {waited:.0f} s for a quiet machine. Each fit in a fresh process of one torch thread; peak RSS "
             f"(`VmHWM`) over the RSS before the fit. *blocks*: the protocol's own `block_samples` (`FitProtocol.block_samples`: "
             "100,000, the latent fit's 40,000); *one batch*: every material in one batch, as before stop 57.", "",
             "| case | materials × samples | capacity | budget | one batch: peak − before, s | blocks: peak − before, s "
             "| blocks | memory ratio | time ratio |",
             "|---|---:|---|---|---:|---:|---:|---:|---:|"]
    def grown(run: dict) -> int:
        return run["peak_bytes"] - run["before_bytes"]

    for row in rows:
        one, blocked = row["one batch"], row["blocks"]
        sizes = (f"{row['materials']} × {row['samples']:,}" if isinstance(row["samples"], int) else
                 " + ".join(f"{row['samples'].count(n)} × {n:,}" for n in dict.fromkeys(row["samples"])))
        lines.append(f"| {row['what']} | {sizes} | {row['capacity']} | "
                     f"{'a few epochs' if row['short'] else 'default'} | {_gib(grown(one))}, {one['seconds']:.1f} | "
                     f"{_gib(grown(blocked))}, {blocked['seconds']:.1f} | {blocked['blocks']} | "
                     f"{grown(blocked) / grown(one):.2f} | {blocked['seconds'] / one['seconds']:.2f} |")
    per_sample = {row["capacity"]: grown(row["one batch"]) / (row["materials"] * row["samples"])
                  for row in rows if row["what"] == "memory"}
    lines += ["", "Per sample fitted at once (one batch): " + ", ".join(
        f"{capacity} {value / 1e3:.1f} kB" for capacity, value in per_sample.items()) + ".", ""]
    return lines


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["--child"]:
        print(json.dumps(child(*json.loads(argv[1]))))
        return 0
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    output_arguments(parser)
    args = parser.parse_args(argv)
    waited = wait_quiet(args.max_wait, 0.3)
    env = machine()
    rows = []
    for what, materials, samples, capacity, short in CASES:
        row = {"what": what, "materials": materials, "samples": samples, "capacity": capacity, "short": short}
        for label, block in (("one batch", ONE_BATCH), ("blocks", None)):
            row[label] = measure(materials, samples, capacity, short, block)
            print(f"{what} {materials}x{samples} {capacity} {label}: {row[label]}", file=sys.stderr)
        rows.append(row)
    if args.json:
        write_json(args.json, {"env": env, "rows": rows})
    command = "python bench/bench_fit_memory.py" + (f" --write {args.write}" if args.write else "")
    publish(markdown_section(env, waited, rows, command), args.write, SECTION)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
