"""Speed of the shipped enhanced GGX against plain GGX and NBRDF (issue 13), side by side in one run.

    python bench/bench_speed.py [--write docs/BENCHMARKS.md]

Per model, one thread, on one material of ``models/enhanced-ggx`` (its first training material;
plain GGX gets the same analytical parameters): evaluations per second at a batch of 100,000
Rusinkiewicz-uniform direction pairs and the time of one call on 300 pairs, for the public
``evaluate`` and for the per-material ``SpecializedBRDF`` (``BRDFModel.specialize``), with the
specialized evaluator's FLOPs per evaluation. NBRDF is a 6-21-21-3 network (Glorot-initialised:
its speed does not depend on its weights).

Training: one step of ``train.train_candidate`` (forward, the log-L1, backward into module weights,
latent and analytical parameters) of the shipped state over all its training materials, at
batches of 4096 and 100,000 samples: the reference path (``forward`` on per-sample gathered
parameters, what training ran before issue 13) against ``forward_indexed`` (per-material work once
per material; the batch in slices of ``train.STEP_ROWS`` rows, ``train.backward_in_slices``, as
``train_candidate`` takes it). ``--compile`` adds ``torch.compile`` of the indexed step (``train.batch_loss``, as
``TrainConfig(compile=True)`` compiles it), in float32 and with bfloat16 matrix products
(``TrainConfig.precision``); compile times reported apart; the pinned torch on this CPU.

ONNX (issue 16): the same materials' ``neuenh.export.onnx.material_graph`` run by onnxruntime (one
intra-op thread, all graph optimizations), measured in the same interleaved run as the torch rows,
reported in their own section at the end (left out when onnxruntime is not installed).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # runnable from a checkout without installing

import torch  # noqa: E402

from bench.harness import Timer, fitting_process, fmt_rate, machine, machine_line, wait_quiet  # noqa: E402
from bench.report import publish  # noqa: E402

SECTION = "## Speed of the enhanced model (issue 13)"
BATCH, SMALL = 100_000, 300


def cases() -> tuple[dict, dict, dict]:
    """(batch cases, small-call cases, FLOPs per evaluation) by row name."""
    from neuenh.data.directions import sample_directions
    from neuenh.models import get_model
    from neuenh.pretrained import load_model
    from neuenh.study.nbrdf_fit import NBRDFNetwork

    enhanced, materials = load_model("enhanced-ggx")
    record = materials.as_params(0)
    plain = get_model("ggx")
    models = {"enhanced GGX": (enhanced, record), "plain GGX": (plain, plain.used_params(record))}
    batch, small, flops = {}, {}, {}
    pairs = {n: tuple(x.float() for x in sample_directions(n, seed=1, anisotropic=True)) for n in (BATCH, SMALL)}
    for name, (model, params) in models.items():
        special = model.specialize(params)
        flops[name] = special.flops_per_evaluation
        session = onnx_session(special)
        for n, table in ((BATCH, batch), (SMALL, small)):
            wi, wo = pairs[n]
            table[f"{name}, evaluate"] = lambda m=model, p=params, wi=wi, wo=wo: m.evaluate(wi, wo, p)
            table[f"{name}, specialized"] = lambda s=special, wi=wi, wo=wo: s(wi, wo)
            if session is not None:
                feed = {"wi": wi.numpy(), "wo": wo.numpy()}
                table[f"{name}, {ONNX}"] = lambda s=session, feed=feed: s.run(None, feed)
    nbrdf = NBRDFNetwork()
    for n, table in ((BATCH, batch), (SMALL, small)):
        table["NBRDF (per material)"] = lambda wi=pairs[n][0], wo=pairs[n][1]: nbrdf.evaluate(wi, wo)
    return batch, small, flops


ONNX = "onnxruntime"  # the path name of the ONNX rows


def onnx_session(special):
    """An onnxruntime session (one thread) of ``special``'s ONNX graph, or None without onnxruntime."""
    try:
        import onnxruntime as ort

        from neuenh.export.onnx import material_graph
    except ImportError:
        return None
    options = ort.SessionOptions()
    options.intra_op_num_threads, options.inter_op_num_threads = 1, 1
    options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    return ort.InferenceSession(material_graph(special), options, providers=["CPUExecutionProvider"])


def onnx_section(batch: dict, small: dict) -> list[str]:
    models = [row.partition(", ")[0] for row in batch if row.endswith(f", {ONNX}")]
    if not models:
        return []
    lines = ["", "**ONNX** (`neuenh.export.onnx.material_graph` in onnxruntime, one thread) beside the torch "
             "specialized evaluator, same materials and pairs:", "",
             "| model | torch evaluations/s, batch 1e5 | onnxruntime | × torch | torch, 300 pairs | onnxruntime "
             "| × torch |", "|---|---:|---:|---:|---:|---:|---:|"]
    for model in models:
        t_b, o_b = batch[f"{model}, specialized"].seconds, batch[f"{model}, {ONNX}"].seconds
        t_s, o_s = small[f"{model}, specialized"].seconds, small[f"{model}, {ONNX}"].seconds
        lines.append(f"| {model} | {fmt_rate(BATCH / t_b)} | {fmt_rate(BATCH / o_b)} | {t_b / o_b:.2f} | "
                     f"{1e3 * t_s:.3f} ms | {1e3 * o_s:.3f} ms | {t_s / o_s:.2f} |")
    return lines


TRAIN_BATCHES = (4096, 100_000)
# --compile's rows: the step as ``TrainConfig(compile=True)`` compiles it, at each precision.
COMPILED = {"torch.compile": "float32", "torch.compile, bfloat16 products": "bfloat16"}


def training_cases(compile_step: bool) -> tuple[dict, dict]:
    """(cases by row name, compile seconds by row name): one training step per case."""
    from neuenh.data.directions import sample_directions
    from neuenh.pretrained import load_model
    from neuenh.train import backward_in_slices, batch_loss, log_l1

    model, materials = load_model("enhanced-ggx")
    cases, compile_s = {}, {}
    for n in TRAIN_BATCHES:
        wi, wo = (x.float() for x in sample_directions(n, seed=2, anisotropic=True))
        material = torch.randint(0, len(materials), (n,), generator=torch.Generator().manual_seed(0))
        with torch.no_grad():
            target = model.forward_indexed(wi, wo, materials.values(), materials.latent, material).clamp_min(0) * 1.1

        def reference(wi=wi, wo=wo, material=material, target=target):
            values, latent = materials.gather(material)
            log_l1(model(wi, wo, values, latent), target, wi).mean().backward()

        step = (wi, wo, target, material)
        cases[f"reference, batch {n}"] = reference
        cases[f"indexed, batch {n}"] = lambda f=batch_loss(model, materials), a=step: backward_in_slices(f, *a)
        if compile_step:
            for path, precision in COMPILED.items():
                compiled = torch.compile(batch_loss(model, materials, precision), dynamic=False)
                start = time.perf_counter()
                backward_in_slices(compiled, *step)
                compile_s[f"{path}, batch {n}"] = time.perf_counter() - start
                cases[f"{path}, batch {n}"] = lambda f=compiled, a=step: backward_in_slices(f, *a)
    return cases, compile_s


def training_section(measured: dict, compile_s: dict) -> list[str]:
    lines = ["", "**Training step** (forward, log-L1, backward into weights, latent and parameters; all "
             "the shipped model's training materials):", "",
             "| path | batch | samples/s | × reference |", "|---|---:|---:|---:|"]
    for row, t in measured.items():
        path, _, batch = row.partition(", batch ")
        ref = measured[f"reference, batch {batch}"].seconds
        note = f" (compile {compile_s[row]:.0f} s)" if row in compile_s else ""
        lines.append(f"| {path}{note} | {int(batch):,} | {fmt_rate(int(batch) / t.seconds)} | {ref / t.seconds:.2f} |")
    return lines


def markdown_section(env: dict, timer: Timer, batch: dict, small: dict, flops: dict, command: str) -> list[str]:
    ggx = batch["plain GGX, specialized"].seconds
    lines = [SECTION, "", f"Command: `{command}`  ", machine_line(env), f"Method: {timer.method()}.", "",
             f"The shipped `models/enhanced-ggx` on its first training material, one torch thread. *Batch*: "
             f"{BATCH:,} Rusinkiewicz-uniform pairs; *300 pairs*: one call (per-call overhead). × GGX: the "
             "evaluations/s ratio to specialized plain GGX.", "",
             "| model | path | evaluations/s, batch 1e5 | × GGX | one call on 300 pairs | FLOPs per evaluation |",
             "|---|---|---:|---:|---:|---:|"]
    for row, t in batch.items():
        model, _, path = row.partition(", ")
        if path == ONNX:
            continue  # onnx_section
        cost = f"{flops[model]:,}" if path == "specialized" else "—"
        lines.append(f"| {model} | {path or 'network'} | {fmt_rate(BATCH / t.seconds)} | {ggx / t.seconds:.2f} | "
                     f"{1e3 * small[row].seconds:.3f} ms | {cost} |")
    special = batch["enhanced GGX, specialized"].seconds
    lines += ["", f"Specialized enhanced / specialized plain GGX: **{ggx / special:.2f}**; specialized enhanced / "
              f"NBRDF: **{batch['NBRDF (per material)'].seconds / special:.2f}**; specialized enhanced / its "
              f"`evaluate`: **{batch['enhanced GGX, evaluate'].seconds / special:.2f}**."]
    return lines


def document(env: dict, timer: Timer, batch: dict, small: dict, flops: dict, training: dict, compile_s: dict,
             command: str) -> str:
    lines = markdown_section(env, timer, batch, small, flops, command) + training_section(training, compile_s) \
        + onnx_section(batch, small)
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--write", metavar="PATH", help="write/replace this section of PATH (docs/BENCHMARKS.md)")
    parser.add_argument("--repeats", type=int, default=9)
    parser.add_argument("--max-background", type=float, default=0.3)
    parser.add_argument("--max-wait", type=float, default=300.0)
    parser.add_argument("--compile", action="store_true", help="add torch.compile of the training step")
    args = parser.parse_args(argv)
    command = "python bench/bench_speed.py" + (" --compile" if args.compile else "") \
        + (f" --write {args.write}" if args.write else "")
    fitting_process()
    wait_quiet(args.max_wait, args.max_background)
    env = machine()
    batch_cases, small_cases, flops = cases()
    timer = Timer(repeats=args.repeats, min_time=0.2, max_background=args.max_background)
    with torch.no_grad():
        batch, small = timer.measure(batch_cases), timer.measure(small_cases)
    train_cases, compile_s = training_cases(args.compile)
    training = timer.measure(train_cases)
    text = document(env, timer, batch, small, flops, training, compile_s, command)
    publish(text, args.write, SECTION)
    return 0


if __name__ == "__main__":
    sys.exit(main())
