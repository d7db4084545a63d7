"""Plain fits (issue 24): plain GGX's default fit beside NBRDF's fit of the same samples, and beside
the default plain fit of an older checkout (``--before-rev``), in one run.

    python bench/bench_plain_fit.py [--before-rev REV] [--rgl DIR] [--json OUT.json] [--write docs/BENCHMARKS.md]

Per RGL material of ``--rgl`` (the visible 8; skipped with a message when absent) and per case of the
report's protocols (uniform 10,000 pairs; half near the mirror, 10,000 and 3,000), the fit and test
sets of the study (``neuenh.study.heldout.draw_fit_test``, seed 0, 10,000 test pairs drawn the same
way), one torch thread: plain GGX by ``fit_materials`` with the checkout's default protocol, and
``NBRDFContender`` (a 6-21-21-3 network per material, its defaults). ``--before-rev``: this file's
plain fits alone, run first in the repository as it was at REV (``git archive``; it uses only the
public fit API). Recorded: wall time of each fit and the held-out log-L1 (``train.log_l1`` on the
test set); ratios are per material first, then the median (worst in brackets). Issue 24's rows: plain
GGX / NBRDF ≤ 0.25× at 10,000; held-out error not worse than before (median ≤ +1 %, worst ≤ +5 %).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # runnable from a checkout without installing

from bench.harness import absent, fitting_process, machine_line, output_arguments, side_by_side, wait_quiet  # noqa: E402

SECTION = "## Plain fits against NBRDF and before (issue 24)"
RGL = ROOT.parent / "shared" / "data" / "rgl"
CASES = (("uniform", 10_000), ("mirror", 10_000), ("mirror", 3_000))
N_TEST = 10_000
OTHER_KERNEL = ("plain GGX (torch)", "plain GGX (jit)")


def run(rgl: Path, with_nbrdf: bool = True) -> dict:
    """{case: {fit: {material: (held-out log-L1, seconds)}}} for every case of CASES, fit "plain GGX"
    (the default protocol) and, ``with_nbrdf``, "NBRDF" and the default fit on the other kernel where
    Dr.Jit is available: "plain GGX (torch)" when the default is the compiled kernel (``neuenh.fit.jit``),
    else "plain GGX (jit)"."""
    from neuenh.data import load_measured
    from neuenh.fit import FitOptions, default_protocol, fit_materials
    from neuenh.models import get_model
    from neuenh.study.efficiency import PROTOCOLS
    from neuenh.study.heldout import draw_fit_test, heldout_log_l1
    from neuenh.train import log_l1

    ggx = get_model("ggx")
    fits = {"plain GGX": default_protocol(ggx)}
    if with_nbrdf:  # the run of this checkout (not --before's): the other kernel beside the default
        from neuenh.fit.jit import available

        if available():
            other = "torch" if fits["plain GGX"].kernel == "jit" else "jit"
            fits[f"plain GGX ({other})"] = FitOptions(kernel=other).protocol_for(ggx)
    out: dict = {}
    for path in sorted(rgl.glob("*.bsdf")):
        material = load_measured(path)
        for protocol, n in CASES:
            case = out.setdefault(f"{protocol} {n:,}", {})
            fit, test, _ = draw_fit_test(material, n, N_TEST, 0, near_mirror=PROTOCOLS[protocol])
            for label, fit_protocol in fits.items():
                start = time.perf_counter()
                result = fit_materials(ggx, fit, fit_protocol, seed=0)
                seconds = time.perf_counter() - start
                case.setdefault(label, {})[material.name] = (heldout_log_l1(ggx, result.materials, test)[0], seconds)
            if with_nbrdf:
                from neuenh.study.contenders import NBRDFContender

                start = time.perf_counter()
                fitted = NBRDFContender().fit(fit)
                seconds = time.perf_counter() - start
                heldout = float(log_l1(fitted.predict(test.wi, test.wo), test.f_r, test.wi).double().mean())
                case.setdefault("NBRDF", {})[material.name] = (heldout, seconds)
            print(f"{protocol:8s} {n:6d} {material.name:24s} " + "  ".join(
                f"{label} {rows[material.name][0]:.5f} {rows[material.name][1]:5.2f} s" for label, rows in case.items()),
                flush=True)
    return out


def markdown_section(env: dict, now: dict, before: dict | None, command: str) -> str:
    lines = [SECTION, "", f"Command: `{command}`  ", machine_line(env), "",
             "Plain GGX fitted by the default protocol to each RGL material (the visible 8), beside NBRDF's fit "
             "of the same samples in the same run and, *before*, the default plain fit of the checkout "
             "`--before-rev` names, run first; wall time of the fit, held-out log-L1 on 10,000 test pairs drawn "
             "the same way; *torch* or *jit*: the default fit on the kernel the default does not use (`FitOptions(kernel=…)`, "
             "`neuenh.fit.jit`), its held-out error against the default's. Ratios per material, then the median "
             "[worst].", "",
             "| case | fit | median s | time / NBRDF | median held-out | held-out / before (torch, jit: / default) |",
             "|---|---|---:|---:|---:|---:|"]
    for case, fits in now.items():
        nbrdf = fits["NBRDF"]
        old = before[case]["plain GGX"] if before else None
        rows_of = [("plain GGX (before)", old)] if old else []
        for label, rows in [*rows_of, *fits.items()]:
            time_ratio = [rows[m][1] / nbrdf[m][1] for m in rows]
            reference = old if label == "plain GGX" else fits["plain GGX"] if label in OTHER_KERNEL else None
            held = [rows[m][0] / reference[m][0] for m in rows] if reference else None
            lines.append(f"| {case} | {label} | {statistics.median(t for _, t in rows.values()):.2f} | "
                         f"{statistics.median(time_ratio):.2f} [{max(time_ratio):.2f}] | "
                         f"{statistics.median(e for e, _ in rows.values()):.4f} | "
                         + (f"{statistics.median(held):.3f} [{max(held):.3f}] |" if held else "— |"))
    materials = list(next(iter(next(iter(now.values())).values())))
    lines += ["", "Per material, held-out log-L1 (seconds):", "",
              "| case, fit | " + " | ".join(materials) + " |", "|---|" + "---:|" * len(materials)]
    for case, fits in now.items():
        old = {"plain GGX (before)": before[case]["plain GGX"]} if before else {}
        for label, rows in {**old, **fits}.items():
            lines.append(f"| {case}, {label} | " + " | ".join(f"{rows[m][0]:.4f} ({rows[m][1]:.1f})" for m in materials) + " |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--before-rev", metavar="REV", help="also run this revision's default plain fit first")
    parser.add_argument("--before", action="store_true", help=argparse.SUPPRESS)  # the run inside --before-rev
    parser.add_argument("--rgl", type=Path, default=RGL, help=f"the RGL materials (default {RGL})")
    output_arguments(parser)
    args = parser.parse_args(argv)
    if absent(args.rgl, "the RGL materials of ../shared"):
        return 0
    fitting_process()  # one torch and one Dr.Jit thread
    wait_quiet(args.max_wait, 0.3)
    side_by_side(args, Path(__file__), lambda before: run(args.rgl, with_nbrdf=not before),
                 ["--rgl", str(args.rgl.resolve())], markdown_section, SECTION, argv)
    return 0


if __name__ == "__main__":
    sys.exit(main())
