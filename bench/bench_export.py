"""Exported models in their real runtimes (issue 16): enhanced against plain GGX, side by side.

    .venv/bin/python bench/bench_export.py --write docs/BENCHMARKS.md

One RGL material (``--material``, default chm_orange) fitted by the shipped ``models/enhanced-ggx``
and by plain GGX on the same 10,000 measurements, then each exported and timed in one interleaved run
(``bench.harness.Timer``):

* **Mitsuba 3** (``llvm_ad_rgb``): the exported scene (``neuenh export --format mitsuba``: the ball
  under the studio environment map, a path tracer of depth 8) rendered at 128² with 64 samples per
  pixel; rays/s = camera rays (pixels × spp) per second. The first render of each scene JIT-compiles
  its kernels and is the warm-up. The paper's anchor: 13.68 vs 21.83 Mrays/s in Mitsuba on an RTX
  3090, a ratio of 0.63.
* **GLSL on Mesa's llvmpipe** (EGL through moderngl): the exported function in a compute shader over
  1,048,576 direction pairs, evaluations/s (dispatch and read-back).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]
from bench.harness import Timer, fmt_rate, machine, machine_line, wait_quiet  # noqa: E402
from bench.report import publish  # noqa: E402

TITLE = "## Exported models in Mitsuba 3 and on llvmpipe (issue 16)"
SIZE, SPP, PAIRS = 128, 64, 1 << 20


def fitted_materials(material: str) -> dict[str, tuple]:
    """label -> (model, the material's fitted parameters)."""
    from neuenh.data.measured import load_measured
    from neuenh.fit import fit_materials
    from neuenh.models import get_model
    from neuenh.pretrained import load_model
    from neuenh.study.heldout import draw_fit_test

    fit, _, _ = draw_fit_test(load_measured(ROOT.parent / "shared" / "data" / "rgl" / f"{material}.bsdf"), 10_000, 1, 0)
    enhanced, trained = load_model("enhanced-ggx")
    out = {}
    for label, model, training in (("enhanced GGX", enhanced, trained), ("plain GGX", get_model("ggx"), None)):
        result = fit_materials(model, fit, trained=training)
        out[label] = result.material_model(model, 0)
    return out


def mitsuba_cases(models: dict, out: Path) -> dict:
    from neuenh.export import mitsuba as nm

    mi = nm.set_variant("llvm_ad_rgb")
    import drjit as dr
    nm.register()
    cases = {}
    for label, (model, params) in models.items():
        folder = out / label.replace(" ", "-")
        nm.write(model, {"m": params}, folder)
        scene = mi.load_file(str(folder / "m.xml"), spp=SPP, size=SIZE)

        def render(scene=scene):
            image = mi.render(scene, seed=0)
            dr.eval(image)
            dr.sync_thread()
            return image

        cases[label] = render
    return cases


def glsl_cases(models: dict) -> dict:
    import torch

    from gl_runtime import HARNESS, gl_context
    from neuenh.export.glsl import material_source

    ctx = gl_context()
    rng = np.random.default_rng(0)
    w = np.abs(rng.normal(size=(2, PAIRS, 3)))
    w /= np.linalg.norm(w, axis=2, keepdims=True)
    pad = lambda a: np.hstack([a, np.zeros((PAIRS, 1))]).astype(np.float32)  # noqa: E731
    buffers = [ctx.buffer(pad(w[0]).tobytes()), ctx.buffer(pad(w[1]).tobytes()), ctx.buffer(reserve=16 * PAIRS)]
    for binding, buffer in enumerate(buffers):
        buffer.bind_to_storage_buffer(binding)
    cases = {}
    for label, (model, params) in models.items():
        source = material_source(model.specialize(params.to(torch.float64)), "m")
        program = ctx.compute_shader(HARNESS.format(source=source, call="neuenh_brdf"))
        program["n"] = PAIRS

        def run(program=program):
            program.run(group_x=PAIRS // 64)
            ctx.finish()

        cases[label] = run
    return cases


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--material", default="chm_orange_rgb")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--write", metavar="FILE")
    args = parser.parse_args()
    env = machine()
    models = fitted_materials(args.material)
    waited = wait_quiet(120, 0.3)
    timer = Timer(args.repeats, min_time=0.5, max_background=0.3)
    with tempfile.TemporaryDirectory() as tmp:
        mitsuba = timer.measure(mitsuba_cases(models, Path(tmp)), warmup=2)
    glsl = timer.measure(glsl_cases(models), warmup=2)
    rays = {k: SIZE * SIZE * SPP / t.seconds for k, t in mitsuba.items()}
    evals = {k: PAIRS / t.seconds for k, t in glsl.items()}
    command = f"python bench/bench_export.py{' --material ' + args.material if args.material != 'chm_orange_rgb' else ''} --write docs/BENCHMARKS.md"
    lines = [TITLE, "", f"Command: `{command}`  ", machine_line(env) + "  ",
             f"Method: {timer.method()} (waited {waited:.0f} s for a quiet machine).", "",
             f"The RGL material {args.material} fitted (10,000 measurements) by the shipped enhanced GGX and by plain "
             "GGX, each exported and run in the runtime, one interleaved run. *Mitsuba*: the exported scene (ball "
             f"under the studio environment, path tracer) at {SIZE}² and {SPP} spp, `llvm_ad_rgb` on the CPU, camera "
             f"rays per second. *llvmpipe*: the exported GLSL function over {PAIRS:,} pairs in a compute shader.", "",
             "| model | Mitsuba rays/s | llvmpipe evaluations/s |", "|---|---:|---:|"]
    for label in models:
        lines.append(f"| {label} | {fmt_rate(rays[label])} | {fmt_rate(evals[label])} |")
    lines += ["", f"Enhanced / plain GGX: **{rays['enhanced GGX'] / rays['plain GGX']:.2f}** in Mitsuba (paper, "
              f"Mitsuba on an RTX 3090: 13.68 / 21.83 = 0.63), **{evals['enhanced GGX'] / evals['plain GGX']:.2f}** on "
              "llvmpipe.", ""]
    publish(lines, args.write, TITLE)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
