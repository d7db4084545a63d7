"""What the jit fit kernel compiles on a machine that has never run it (issue 24): the shipped model's
default latent fit of one RGL material, then of two at once, on an empty Dr.Jit kernel cache and again
on the cache it left, in this checkout and (``--before-rev``) in an older one, in the same run.

    python bench/bench_fit_compile.py [--before-rev REV] [--rgl DIR] [--json OUT.json] [--write docs/BENCHMARKS.md]

Each pass is a new process of one thread (``fitting_process``) whose ``HOME`` is a new temporary folder,
so Dr.Jit's disk cache (``$HOME/.drjit``) starts empty and the user's own is never touched; the second
pass reuses the first's folder. Per fit: its wall time, the kernels Dr.Jit compiled (its kernel history:
neither an in-memory nor a disk-cache hit) with their build seconds, the kernels read from the disk
cache, and the fit losses (the same to the last digit before and after, when only compiles changed).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # runnable from a checkout without installing

from bench.harness import absent, fitting_process, machine_line, output_arguments, side_by_side, wait_quiet  # noqa: E402

SECTION = "## The jit fit kernel's compiles (issue 24)"
RGL = ROOT.parent / "shared" / "data" / "rgl"
MATERIALS = ("paper_white_rgb", "chm_orange_rgb")  # the first fitted alone, then both at once
FIT_SAMPLES = 3000  # the README's fit: half of them near the mirror direction


def child(rgl: Path) -> list[dict]:
    """In this process: the fit of the first material, then of both; what each compiled."""
    fitting_process()
    import drjit as dr

    from neuenh.data import load_measured
    from neuenh.data.samples import Samples
    from neuenh.fit import fit_materials
    from neuenh.fit.jit import available
    from neuenh.pretrained import load_model
    from neuenh.study.heldout import draw_fit_test

    if not available():
        raise SystemExit("Dr.Jit's LLVM backend is not available: nothing to compile")
    model, trained = load_model("enhanced-ggx")
    fits = [draw_fit_test(load_measured(rgl / f"{name}.bsdf"), FIT_SAMPLES, 1, 0, near_mirror=0.5)[0]
            for name in MATERIALS]
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    out = []
    for k in (1, 2):
        dr.kernel_history()  # empties it
        began = time.perf_counter()
        result = fit_materials(model, Samples.concat(fits[:k]), seed=0, trained=trained)
        wall = time.perf_counter() - began
        kernels = [e for e in dr.kernel_history() if e["type"] == dr.KernelType.JIT]
        built = [e for e in kernels if not e["cache_hit"] and not e["cache_disk"]]
        out.append({"materials": k, "wall_s": wall, "compiled": len(built),
                    "build_s": sum(e["backend_time"] for e in built) / 1e3,
                    "disk_reads": sum(bool(e["cache_disk"]) for e in kernels), "losses": result.losses})
    return out


def run(rgl: Path) -> list[list[dict]]:
    """[cold pass, warm pass], each ``child``'s fits, in new processes sharing one empty ``HOME``."""
    with tempfile.TemporaryDirectory(prefix="bench-drjit-home-") as home:
        env = {**os.environ, "HOME": home}
        passes = []
        for _ in range(2):
            done = subprocess.run([sys.executable, __file__, "--child", "--rgl", str(rgl)], env=env, check=True,
                                  capture_output=True, text=True)
            passes.append(json.loads(done.stdout.strip().splitlines()[-1]))
        return passes


def markdown_section(env: dict, now: list, before: list | None, command: str) -> str:
    lines = [SECTION, "", f"Command: `{command}`  ", machine_line(env), "",
             f"The shipped model's default fit (`fit_materials`, latent capacity, the jit kernel) of {MATERIALS[0]}, "
             f"then of it and {MATERIALS[1]} at once ({FIT_SAMPLES:,} samples each, half near the mirror), in a new "
             "process of one thread whose Dr.Jit disk cache starts empty (*cold*), then in another process on the "
             "cache the first left (*warm*). *Compiled*: kernels Dr.Jit built (build seconds); *disk*: kernels read "
             "from its disk cache. *Before*: the checkout `--before-rev` names, run first.", "",
             "| checkout | pass | fit | wall s | compiled (build s) | disk | losses |", "|---|---|---|---:|---:|---:|---|"]
    for label, passes in (("before", before), ("now", now)):
        for name, fits in zip(("cold", "warm"), passes or ()):
            for fit in fits:
                losses = ", ".join(f"{x:.9g}" for x in fit["losses"])
                lines.append(f"| {label} | {name} | {fit['materials']} material(s) | {fit['wall_s']:.2f} | "
                             f"{fit['compiled']} ({fit['build_s']:.1f}) | {fit['disk_reads']} | {losses} |")
    if before:
        same = all(a["losses"] == b["losses"] for p, q in zip(before, now) for a, b in zip(p, q))
        lines += ["", f"Losses before and now equal to the last digit: {'yes' if same else 'NO'}."]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--before-rev", metavar="REV", help="also run this revision first")
    parser.add_argument("--before", action="store_true", help=argparse.SUPPRESS)  # the run inside --before-rev
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)  # one pass, in its own process
    parser.add_argument("--rgl", type=Path, default=RGL, help=f"the RGL materials (default {RGL})")
    output_arguments(parser)
    args = parser.parse_args(argv)
    if args.child:
        print(json.dumps(child(args.rgl)))
        return 0
    if absent(args.rgl, "the RGL materials of ../shared"):
        return 0
    wait_quiet(args.max_wait, 0.3)
    side_by_side(args, Path(__file__), lambda before: run(args.rgl), ["--rgl", str(args.rgl.resolve())],
                 markdown_section, SECTION, argv)
    return 0


if __name__ == "__main__":
    sys.exit(main())
