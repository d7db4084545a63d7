"""Exported models in their real runtimes (issues 16, 24): enhanced against plain GGX, side by side.

    .venv/bin/python bench/bench_export.py [--before-rev REV] --write docs/BENCHMARKS.md

One RGL material (``--material``, default chm_orange) fitted by the shipped ``models/enhanced-ggx``,
by plain GGX and by a per-material NBRDF network (a scene plan's ``nbrdf`` rung) on the same 10,000
measurements, each fit's held-out log-L1 measured on 10,000 others drawn alike (half of both near the
mirror direction), then each exported and timed in one interleaved run (``bench.harness.Timer``):

* **Mitsuba 3** (``llvm_ad_rgb``): the exported scene (``neuenh export --format mitsuba``: the ball
  under the studio environment map, a path tracer of depth 8) rendered at 128² with 64 samples per
  pixel; rays/s = camera rays (pixels × spp) per second. The first render of each scene JIT-compiles
  its kernels and is the warm-up. Each scene renders in its own process, as a user renders one
  (``RenderWorkers``), the two interleaved. Beside the wall time of ``mi.render`` (tracing the
  integrator and the plugin in Python, then running the kernels), the kernels' own time (Dr.Jit's
  kernel history): the throughput a render large enough to hide the tracing reaches. The paper's
  anchor: 13.68 vs 21.83 Mrays/s in Mitsuba on an RTX 3090, a ratio of 0.63. ``--before-rev``: the
  same Mitsuba measurement in the repository at that revision (``bench.harness.run_at_revision``),
  run first.
* **GLSL on Mesa's llvmpipe** (EGL through moderngl): the exported function in a compute shader over
  1,048,576 direction pairs, evaluations/s (dispatch and read-back).
"""

from __future__ import annotations

import argparse
import functools
import json
import statistics
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]
from bench.harness import Timer, fmt_rate, machine, machine_line, run_at_revision, wait_quiet, write_json  # noqa: E402
from bench.report import publish  # noqa: E402

TITLE = "## Exported models in Mitsuba 3 and on llvmpipe (issue 16)"
SIZE, SPP, PAIRS = 128, 64, 1 << 20


RGL = ROOT.parent / "shared" / "data" / "rgl"


@dataclass
class Case:
    """One fitted material, exported: its held-out log-L1, ``write_mitsuba(folder)`` -> its scene file,
    ``glsl()`` -> its GLSL source (``neuenh_m_brdf``, and ``neuenh_brdf``)."""

    heldout: float
    write_mitsuba: Callable[[Path], Path]
    glsl: Callable[[], str]


def fitted_materials(material: str, rgl: Path) -> dict[str, Case]:
    """label -> the material fitted by that model (``Case``), in the table's order."""
    import torch

    from neuenh.data.measured import load_measured
    from neuenh.export import export_nbrdf, mitsuba as nm
    from neuenh.export.glsl import material_source, nbrdf_source
    from neuenh.fit import fit_materials
    from neuenh.models import get_model
    from neuenh.pretrained import load_model
    from neuenh.study.heldout import draw_fit_test, heldout_log_l1
    from neuenh.study.nbrdf_fit import fit_nbrdf
    from neuenh.train import log_l1

    fit, test, _ = draw_fit_test(load_measured(rgl / f"{material}.bsdf"), 10_000, 10_000, 0, near_mirror=0.5)
    enhanced, trained = load_model("enhanced-ggx")
    out = {}
    for label, model, training in (("enhanced GGX", enhanced, trained), ("plain GGX", get_model("ggx"), None)):
        result = fit_materials(model, fit, trained=training)
        own, params = result.material_model(model, 0)

        def write(folder: Path, own=own, params=params) -> Path:
            nm.write(own, {"m": params}, folder)
            return folder / "m.xml"

        out[label] = Case(heldout_log_l1(model, result, test)[0], write,
                          lambda own=own, params=params: material_source(own.specialize(params.to(torch.float64)), "m"))
    net = fit_nbrdf(fit).networks[0]
    with torch.no_grad():
        heldout = float(log_l1(net(test.wi, test.wo), test.f_r, test.wi).double().mean())

    def write_network(folder: Path) -> Path:
        export_nbrdf({"m": net}, "mitsuba", folder)
        return folder / "m.xml"

    out["NBRDF (per material)"] = Case(heldout, write_network, lambda: nbrdf_source(net, "m"))
    return out


def render_worker(scene_file: str) -> int:
    """``--render-worker``: load the exported scene, then per line read from stdin render it once and
    answer one JSON line: the render's kernels' seconds (Dr.Jit's kernel history) and this process's
    CPU seconds so far."""
    import resource

    from neuenh.export import mitsuba as nm

    mi = nm.set_variant("llvm_ad_rgb")
    import drjit as dr
    nm.register()
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    scene = mi.load_file(scene_file, spp=SPP, size=SIZE)
    for _ in sys.stdin:
        dr.kernel_history()  # empties it
        dr.eval(mi.render(scene, seed=0))
        dr.sync_thread()
        kernels = sum(k["execution_time"] for k in dr.kernel_history()) / 1e3
        usage = resource.getrusage(resource.RUSAGE_SELF)
        print(json.dumps({"kernels": kernels, "cpu": usage.ru_utime + usage.ru_stime}), flush=True)
    return 0


class RenderWorkers:
    """One ``render_worker`` process per exported scene, each rendering when asked: a user renders one
    scene per process, and two scenes in one process would change the kernels (Dr.Jit traces every
    registered BSDF instance into the virtual call of each, so the plain scene would trace and carry
    the enhanced plugin too). ``cpu()`` is the workers' CPU seconds so far, for ``Timer``'s
    background probe; ``kernel_seconds[label]`` the kernels' seconds of each render."""

    def __init__(self, scenes: dict[str, Path]):
        self.procs = {label: subprocess.Popen([sys.executable, __file__, "--render-worker", str(path)], text=True,
                                              stdin=subprocess.PIPE, stdout=subprocess.PIPE)
                      for label, path in scenes.items()}
        self.worker_cpu = dict.fromkeys(scenes, 0.0)
        self.kernel_seconds: dict[str, list[float]] = {label: [] for label in scenes}

    def render(self, label: str) -> None:
        proc = self.procs[label]
        proc.stdin.write("render\n")
        proc.stdin.flush()
        line = proc.stdout.readline()
        if not line:
            raise RuntimeError(f"the render worker of {label} exited ({proc.wait()})")
        answer = json.loads(line)
        self.kernel_seconds[label].append(answer["kernels"])
        self.worker_cpu[label] = answer["cpu"]

    def cpu(self) -> float:
        return sum(self.worker_cpu.values())

    def close(self) -> None:
        for proc in self.procs.values():
            proc.stdin.close()
            proc.wait()


def glsl_cases(models: dict[str, Case]) -> dict:
    from gl_runtime import HARNESS, gl_context

    ctx = gl_context()
    rng = np.random.default_rng(0)
    w = np.abs(rng.normal(size=(2, PAIRS, 3)))
    w /= np.linalg.norm(w, axis=2, keepdims=True)
    pad = lambda a: np.hstack([a, np.zeros((PAIRS, 1))]).astype(np.float32)  # noqa: E731
    buffers = [ctx.buffer(pad(w[0]).tobytes()), ctx.buffer(pad(w[1]).tobytes()), ctx.buffer(reserve=16 * PAIRS)]
    for binding, buffer in enumerate(buffers):
        buffer.bind_to_storage_buffer(binding)
    cases = {}
    for label, case in models.items():
        program = ctx.compute_shader(HARNESS.format(source=case.glsl(), call="neuenh_brdf"))
        program["n"] = PAIRS

        def run(program=program):
            program.run(group_x=PAIRS // 64)
            ctx.finish()

        cases[label] = run
    return cases


def measure_mitsuba(models: dict[str, Case], repeats: int) -> tuple[dict[str, dict[str, float]], Timer]:
    """label -> {"rays": camera rays/s of ``mi.render``, "kernel_rays": of its kernels alone}, each
    scene rendered in its own process (``RenderWorkers``), interleaved; and the timer that measured."""
    with tempfile.TemporaryDirectory() as tmp:
        scenes = {label: case.write_mitsuba(Path(tmp) / str(i)) for i, (label, case) in enumerate(models.items())}
        workers = RenderWorkers(scenes)
        try:
            timer = Timer(repeats, min_time=0.5, max_background=0.3, other_own_cpu=workers.cpu)
            timings = timer.measure({label: functools.partial(workers.render, label) for label in scenes}, warmup=2)
        finally:
            workers.close()
    rays = SIZE * SIZE * SPP
    # the kernels' median over every render after the first (which compiles them)
    return {k: {"rays": rays / t.seconds, "kernel_rays": rays / statistics.median(workers.kernel_seconds[k][1:])}
            for k, t in timings.items()}, timer


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--material", default="chm_orange_rgb")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--before-rev", metavar="REV", help="also measure Mitsuba at this revision, first")
    parser.add_argument("--rgl", type=Path, default=RGL, help=f"RGL's measured materials (default {RGL})")
    parser.add_argument("--mitsuba-only", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--json", type=Path, help="write the raw numbers here")
    parser.add_argument("--max-wait", type=float, default=120.0)
    parser.add_argument("--write", metavar="FILE")
    parser.add_argument("--render-worker", metavar="SCENE", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.render_worker:
        return render_worker(args.render_worker)
    env = machine()
    before = None
    if args.before_rev:
        before = run_at_revision(args.before_rev, Path(__file__), [
            "--material", args.material, "--repeats", str(args.repeats), "--rgl", str(args.rgl.resolve()),
            "--mitsuba-only"])
    models = fitted_materials(args.material, args.rgl)
    waited = wait_quiet(args.max_wait, 0.3)
    mitsuba, mitsuba_timer = measure_mitsuba(models, args.repeats)
    if args.mitsuba_only:
        write_json(args.json, {"mitsuba": mitsuba, "method": mitsuba_timer.method()})
        return 0
    timer = Timer(args.repeats, min_time=0.5, max_background=0.3)
    glsl = timer.measure(glsl_cases(models), warmup=2)
    evals = {k: PAIRS / t.seconds for k, t in glsl.items()}
    if args.json:
        write_json(args.json, {"mitsuba": mitsuba, "glsl": evals, "before": before,
                               "heldout": {label: case.heldout for label, case in models.items()}})
    lines = [TITLE, "", f"Command: `{' '.join(['python bench/bench_export.py', *sys.argv[1:]])}`  ",
             machine_line(env) + "  ",
             f"Method: Mitsuba {mitsuba_timer.method()}; llvmpipe {timer.method()} (waited {waited:.0f} s for a quiet "
             "machine).", "",
             f"The RGL material {args.material} fitted (10,000 measurements, half near the mirror direction) by the "
             "shipped enhanced GGX, by plain GGX and by a per-material NBRDF network, each fit's held-out log-L1 on "
             "10,000 other pairs drawn alike, each exported and run in the runtime, one interleaved run. *Mitsuba*: "
             "the exported scene (ball "
             f"under the studio environment, path tracer) at {SIZE}² and {SPP} spp, `llvm_ad_rgb` on the CPU, each scene "
             "in its own process, camera rays per second of `mi.render` and of its kernels alone (without tracing "
             f"the integrator and the plugin in Python). *llvmpipe*: the exported GLSL function over {PAIRS:,} pairs "
             "in a compute shader.", "",
             "| model | held-out log-L1 | Mitsuba rays/s | of its kernels | llvmpipe evaluations/s |",
             "|---|---:|---:|---:|---:|"]
    cases = [(label, f"{models[label].heldout:.4f}", mitsuba[label], fmt_rate(evals[label])) for label in models]
    if before:
        cases += [(f"{label}, at {args.before_rev}", "", before["mitsuba"][label], "") for label in before["mitsuba"]]
    for label, heldout, m, glsl_rate in cases:
        lines.append(f"| {label} | {heldout} | {fmt_rate(m['rays'])} | {fmt_rate(m['kernel_rays'])} | {glsl_rate} |")
    ratio = lambda m, key: m["enhanced GGX"][key] / m["plain GGX"][key]  # noqa: E731
    nbrdf = lambda m, key: m["NBRDF (per material)"][key] / m["plain GGX"][key]  # noqa: E731
    lines += ["", f"Enhanced / plain GGX: **{ratio(mitsuba, 'rays'):.2f}** in Mitsuba, **{ratio(mitsuba, 'kernel_rays'):.2f}** "
              "in its kernels alone (paper, Mitsuba on an RTX 3090: 13.68 / 21.83 = 0.63), "
              f"**{evals['enhanced GGX'] / evals['plain GGX']:.2f}** on llvmpipe. NBRDF / plain GGX: "
              f"{nbrdf(mitsuba, 'rays'):.2f} in Mitsuba, {nbrdf(mitsuba, 'kernel_rays'):.2f} in its kernels, "
              f"{evals['NBRDF (per material)'] / evals['plain GGX']:.2f} on llvmpipe."]
    if before:
        lines += [f"At {args.before_rev} (run first, {before['method']}): **{ratio(before['mitsuba'], 'rays'):.2f}** in "
                  f"Mitsuba, **{ratio(before['mitsuba'], 'kernel_rays'):.2f}** in its kernels alone."]
    publish(lines + [""], args.write, TITLE)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
