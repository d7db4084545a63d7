"""Issue 23's experiment: does the fit score track generalisation where the validation loss does not?

    python bench/bench_selection.py --json OUT.json [--model enhanced-ggx] [--rungs all|final]
                                    [--extra NAME=BUNDLE ...] [--search DATA_DIR]
                                    [--zoo 16] [--ggx 8] [--seed 1000] [--phases score rgl-score ...]
                                    [--merl-spec SPEC.yaml] [--against LABEL] [--workers 2]
                                    [--write docs/BENCHMARKS.md]

Every rung of ``--model`` (each committed round's winner of the search that made it,
``neuenh.pretrained.rungs``; ``--rungs final``: the shipped state only), every ``--extra`` bundle,
each committed round's winner of the search in ``--search`` (a ``neuenh search --data-dir`` folder,
finished or not: its only job's checkpoints) and plain GGX are scored by
``neuenh.selection.fit_score`` — modules frozen, each material's parameters fitted to part of its
samples, the log-L1 measured on others — on materials none of them trained on, in *phases*:

=============  =====================================  ===========================================
phase          materials                              fit (``FitScoreConfig``), sampling
=============  =====================================  ===========================================
``score``      held out from the training sources:    the search's budget (examples/reference-fit.yaml's
               ``--zoo`` synthetic zoo (seed          ``search.fit_score``, read from it: 800 fit / 2,000
               ``--seed`` + 5), ``--ggx`` noisy GGX   test samples, 300 epochs), a quarter of the pairs
                                                      near the mirror (as trained)
               (``--seed`` + 4, noise 0.1)
``user``       the same held-out materials            the user's fit (``neuenh fit``'s default 300
                                                      epochs) to 3,000 samples, 1,000 tested, half
                                                      near the mirror (issue 23's protocol)
``score2``     a second draw (``--seed`` + 1000 + 5,  the search's budget: is the score's order stable?
               + 4)
``merl-user``  the NBRDF stand-ins (MERL) that         the user's fit
               ``--merl-spec``'s ``nbrdf`` source holds
               out (``holdout: N``)
``merl-auto``  the same stand-ins                     the user's fit at ``neuenh fit``'s default
                                                      capacity (``auto``: corrections where a
                                                      material's cross-validation chooses them)
``rgl-score``  the 8 RGL materials (final check only)  the search's budget
``rgl-user``   the 8 RGL materials (final check only)  the user's fit (issue 23's protocol)
=============  =====================================  ===========================================

The shipped models' searches drew their synthetic materials with seeds 5 and 4, so the held-out
draws share the sources' families and distributions but no material. Those draws are synthetic
alone, and they did not predict the visible RGL materials (docs/BENCHMARKS.md, "Stop 59: a prior
on the training codes"): the ``merl-user`` and ``merl-auto`` phases score real measurements (the
NBRDF stand-ins of MERL) kept out of training by a spec's ``holdout``, and only for models that did
not train on any of them (every shipped model trained on all 100; a model that did is listed, not
scored). RGL materials are measured
only, never tuned on. Beside each model its in-sample validation loss, what its search selected by.

Results go to ``--json`` after every finished (phase, group, model) unit, atomically; a rerun with
the same draws skips the units already there (resumable), so a model can be added to a comparison
without scoring the others again. The section is written from whatever units are complete; a missing
cell reads "—". ``--workers`` processes run units in parallel, one torch thread each. ``--against
LABEL`` adds every other model paired with that one, material by material (``paired``).
"""

from __future__ import annotations

import argparse
import json
import math
import random
import statistics
import sys
import time
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # runnable from a checkout without installing

from bench.harness import fitting_process, machine, machine_line  # noqa: E402
from bench.report import publish  # noqa: E402
from neuenh.files import atomic_write  # noqa: E402

SECTION = "## Selection by generalisation: the experiment (issue 23)"
RGL = ROOT.parent / "shared" / "data" / "rgl"


@dataclass(frozen=True)
class Contender:
    """A model to score: its label, in-sample validation loss, the model, its training materials (the
    fit's starts; None for plain GGX), where it was read (what a resumed unit must match) and the names
    of the materials it trained on (a rung's fit starts are codes without names)."""

    label: str
    val: float
    model: object
    trained: object
    source: str
    training_names: tuple[str, ...] = ()


@dataclass(frozen=True)
class Protocol:
    """How a phase fits and measures: samples drawn per material, the share near the mirror, and
    the fit score's budget and capacity (``FitScoreConfig``: fit samples, test samples, epochs, capacity)."""

    near_mirror: float
    fit_samples: int
    test_samples: int
    epochs: int
    capacity: str = "latent"

    @property
    def samples(self) -> int:
        return self.fit_samples + self.test_samples


def search_protocol(spec_path: Path = ROOT / "examples" / "reference-fit.yaml") -> Protocol:
    """The fit score's budget of the fit-scored reference search and its sources' share of pairs
    near the mirror, read from its spec so that the ``score`` phases measure what the search selects
    by (a copy of it here kept 80 epochs after the spec moved to 300)."""
    from neuenh_service.orchestrator.spec import load_spec

    spec = load_spec(spec_path)
    shares = {source.near_mirror for source in spec.data}
    if len(shares) != 1:
        raise SystemExit(f"{spec_path}: its sources draw {sorted(shares)} of their pairs near the mirror; "
                         "the score phases need one share")
    budget = spec.search.fit_score
    return Protocol(shares.pop(), budget.fit_samples, budget.test_samples, budget.epochs)


SEARCH = search_protocol()
USER = Protocol(0.5, 3_000, 1_000, 300)  # issue 23: 3,000 fitted, half near the mirror, 1,000 held out; neuenh fit
USER_AUTO = Protocol(0.5, 3_000, 1_000, 300, "auto")  # the same at neuenh fit's default capacity
PHASES = {  # phase -> (groups, protocol, seed offset of the synthetic draws)
    "score": (("zoo", "ggx"), SEARCH, 0),
    "user": (("zoo", "ggx"), USER, 0),
    "score2": (("zoo", "ggx"), SEARCH, 1000),
    "merl-user": (("merl",), USER, 0),
    "merl-auto": (("merl",), USER_AUTO, 0),
    "rgl-score": (("rgl",), SEARCH, 0),
    "rgl-user": (("rgl",), USER, 0),
}


def merl_phases(phases: list[str]) -> list[str]:
    """Those of ``phases`` that score the held-out MERL stand-ins (they need ``--merl-spec``)."""
    return [phase for phase in phases if "merl" in PHASES[phase][0]]


def search_rounds(data_dir: str) -> list[tuple[int, object]]:
    """(round, winner's ``Bundle``) of every committed round of the only job in a ``neuenh search
    --data-dir`` folder, read from its job store and checkpoints."""
    from neuenh.checkpoint import Bundle
    from neuenh_service.storage import LocalArtifactStore, SQLiteJobStore

    with SQLiteJobStore(Path(data_dir) / "jobs.sqlite") as store:
        jobs = store.list_jobs().jobs
        if len(jobs) != 1:
            raise SystemExit(f"--search {data_dir}: expected one job in its store, found {len(jobs)}")
        rounds = store.rounds(jobs[0].id)
    artifacts = LocalArtifactStore(Path(data_dir) / "artifacts")
    return [(r.index, Bundle.from_bytes(artifacts.get(r.artifact_key))) for r in rounds if r.artifact_key]


def contenders(model: str, extras: dict[str, str], search: str | None = None,
               rung_choice: str = "all") -> list[Contender]:
    """Every rung of ``model`` (the last only for ``rung_choice`` "final"), every extra bundle, every
    committed round of ``search`` and plain GGX. A fit starts from the training materials as ``neuenh fit`` and the search's fit score
    do (their mean code and the codes that fit a material best): a bundle's own for the model itself,
    an extra bundle and a search round; a rung, its round's (``Rung.trained``: their mean alone for the
    earlier rungs of a bundle written before stop 57).
    (Until stop 56 every contender had the mean alone: the runs recorded before fitted from fewer starts.)"""
    from neuenh.checkpoint import Bundle
    from neuenh.models import get_model
    from neuenh.pretrained import load_model, rungs

    every = rungs(model)
    names = lambda table: tuple(table.names) if table is not None else ()
    model_names = names(load_model(model)[1])  # every rung of one bundle trained on its materials
    out = [Contender(f"{model}@{r.round}:{r.state}", r.val_loss, r.model, r.trained(), model, model_names)
           for r in (every[-1:] if rung_choice == "final" else every)]
    for name, path in extras.items():
        bundle = Bundle.load(path)
        val = float(bundle.metrics.get("val_loss", float("nan")))
        out.append(Contender(f"{name}:{bundle.model.state}", val, bundle.model, bundle.materials,
                             str(Path(path).resolve()), names(bundle.materials)))
    for k, bundle in search_rounds(search) if search else ():
        val = float(bundle.metrics.get("val_loss", float("nan")))
        out.append(Contender(f"search@{k}:{bundle.model.state}", val, bundle.model, bundle.materials,
                             f"{search}@{k}", names(bundle.materials)))
    out.append(Contender("ggx", float("nan"), get_model("ggx"), None, "ggx"))
    return out


def draw(group: str, protocol: Protocol, args, offset: int):
    """The samples of one group of materials under ``protocol`` (a data source, as a job draws them)."""
    from neuenh.data.sources import RGLSource, SyntheticGGX, SyntheticZoo

    common = {"samples": protocol.samples, "near_mirror": protocol.near_mirror}
    if group == "zoo":
        return SyntheticZoo(source="synthetic_zoo", materials=args.zoo, seed=args.seed + offset + 5, **common).build()
    if group == "ggx":
        return SyntheticGGX(source="synthetic_ggx", materials=args.ggx, seed=args.seed + offset + 4, noise=0.1,
                            **common).build()
    if group == "merl":
        from neuenh.data.sources import held_out

        source = merl_source(args.merl_spec)
        drawn = source.model_copy(update={**common, "seed": args.seed + offset + 3, "holdout": 0}).build()
        return drawn.select(held_out(source, len(drawn.names)))  # the materials every search of it keeps out
    return RGLSource(source="rgl", paths=[str(p) for p in sorted(Path(args.rgl).glob("*.bsdf"))], seed=0,
                     every_azimuth=True, **common).build()


def merl_source(spec_path: Path):
    """The one ``nbrdf`` source of a search spec that holds materials out."""
    from neuenh_service.orchestrator.spec import load_spec

    sources = [s for s in load_spec(spec_path).data if s.source == "nbrdf" and s.holdout]
    if len(sources) != 1:
        raise SystemExit(f"--merl-spec {spec_path}: needs exactly one nbrdf source with a holdout, found {len(sources)}")
    return sources[0]


_MODELS: list = []


def _init(labels: list[str], *chosen) -> None:
    """A worker's models: ``contenders(*chosen)`` in the order of the parent's ``labels`` (a search
    may commit another round between the parent's listing and the worker's)."""
    fitting_process()
    by_label = {c.label: c for c in contenders(*chosen)}
    _MODELS[:] = [by_label[label] for label in labels]


def _score(index: int, holdout, protocol: Protocol) -> dict:
    from neuenh.selection import fit_score
    from neuenh.train import FitScoreConfig

    contender = _MODELS[index]
    scored = fit_score(contender.model, holdout,
                       FitScoreConfig(protocol.fit_samples, protocol.test_samples, protocol.epochs,
                                      capacity=protocol.capacity),
                       trained=contender.trained)
    return {"per_material": dict(zip(holdout.names, scored.per_material)), "wall_s": scored.wall_s}


# What a unit's samples and fits depend on beside its model: a file drawn otherwise is not resumed.
DRAWN_BY = ("zoo", "ggx", "seed", "score_budget", "starts")


def unit_key(phase: str, group: str, label: str) -> str:
    return f"{phase}|{group}|{label}"


def save(path: Path, results: dict) -> None:
    atomic_write(path, json.dumps(results, indent=1))


def check_against(label: str | None, labels: list[str]) -> None:
    if label is not None and label not in labels:
        raise SystemExit(f"--against {label}: not a scored model; the models are {', '.join(labels)}")


def run(args, config: dict) -> dict:
    """Every (phase, group, model) unit not yet in ``args.json``, written there as each finishes. The
    file's units are kept while the draws are the same (``DRAWN_BY``) and each model is read from where
    it was: a model added to the comparison runs alone, one whose bundle moved runs again."""
    results = json.loads(args.json.read_text()) if args.json.exists() else {}
    if {k: results.get("config", {}).get(k) for k in DRAWN_BY} != {k: config.get(k) for k in DRAWN_BY}:
        results = {"units": {}, "sources": {}}
    if results.get("config", {}).get("merl_spec") != config.get("merl_spec"):  # other MERL materials held out
        results["units"] = {key: unit for key, unit in results["units"].items() if key.split("|")[1] != "merl"}
    results["config"] = config
    chosen = (args.model, config["extras"], config.get("search"), config.get("rungs", "all"))
    models = contenders(*chosen)
    moved = {c.label for c in models if results.get("sources", {}).get(c.label) != c.source}
    results["units"] = {key: unit for key, unit in results["units"].items() if key.split("|", 2)[2] not in moved}
    results["sources"] = {**results.get("sources", {}), **{c.label: c.source for c in models}}
    results["models"] = [(c.label, c.val) for c in models]
    check_against(args.against, [c.label for c in models])  # before hours of scoring, not after
    save(args.json, results)
    drawn: dict = {}

    def samples_of(phase: str, group: str):  # each (phase, group)'s materials, drawn once
        if (phase, group) not in drawn:
            _, protocol, offset = PHASES[phase]
            drawn[(phase, group)] = draw(group, protocol, args, offset)
        return drawn[(phase, group)]

    if merl := merl_phases(args.phases):  # a model that trained on some of the held-out materials is not scored on them
        held = samples_of(merl[0], "merl")
        seen = {c.label: sorted(set(held.names) & set(c.training_names)) for c in models}
        results["merl_seen"] = {label: names for label, names in seen.items() if names}
    results.setdefault("merl_seen", {})
    todo = [(phase, group, i) for phase in args.phases for group in PHASES[phase][0]
            if group != "rgl" or Path(args.rgl).is_dir()
            for i in range(len(models)) if unit_key(phase, group, models[i].label) not in results["units"]
            and (group != "merl" or models[i].label not in results["merl_seen"])]
    print(f"{len(todo)} units to run, {len(results['units'])} done", flush=True)
    with ProcessPoolExecutor(args.workers, initializer=_init,
                             initargs=([c.label for c in models], *chosen)) as pool:
        running = {}
        for phase, group, i in todo:
            running[pool.submit(_score, i, samples_of(phase, group), PHASES[phase][1])] = (phase, group, models[i].label)
        while running:
            done, _ = wait(running, return_when=FIRST_COMPLETED)
            for future in done:
                phase, group, label = running.pop(future)
                try:
                    unit = future.result()
                except Exception as error:  # noqa: BLE001 — one failed unit must not lose the others
                    print(f"FAILED {phase} {group} {label}: {error!r}", flush=True)
                    continue
                results["units"][unit_key(phase, group, label)] = unit
                save(args.json, results)
                values = list(unit["per_material"].values())
                print(f"{time.strftime('%H:%M:%S')} {phase:9s} {group:3s} {label:32s} mean {sum(values) / len(values):.4f}"
                      f"  median {statistics.median(values):.4f}  {unit['wall_s']:6.1f} s", flush=True)
    return results


# -- the section ------------------------------------------------------------------------------------
def per_material(results: dict, phase: str, groups: tuple[str, ...], label: str) -> dict[str, float] | None:
    """``label``'s held-out log-L1 in ``phase`` per material of ``groups`` (keyed ``group/name``); None
    unless every group's unit is complete."""
    values = {}
    for group in groups:
        unit = results["units"].get(unit_key(phase, group, label))
        if unit is None:
            return None
        values.update((f"{group}/{name}", v) for name, v in unit["per_material"].items())
    return values


def cell(results: dict, phase: str, groups: tuple[str, ...], label: str) -> float | None:
    """The mean over the materials of ``groups`` of ``label``'s held-out log-L1 in ``phase`` (the fit
    score's own aggregate); None unless every group's unit is complete."""
    values = per_material(results, phase, groups, label)
    return None if values is None else sum(values.values()) / len(values)


def paired(results: dict, phase: str, groups: tuple[str, ...], label: str,
           reference: str) -> tuple[float, float, int, int] | None:
    """``label`` against ``reference`` on the materials both were scored on in ``phase``: the geometric
    mean of their per-material ratios, its standard error as a factor (exp of the log ratios' standard
    deviation over sqrt(n)), on how many materials ``label`` is lower, and n. A mean over materials
    is ruled by the few hardest; the paired ratio asks whether a model fits most materials better.
    None unless both have every group's unit."""
    ours, theirs = per_material(results, phase, groups, label), per_material(results, phase, groups, reference)
    if ours is None or theirs is None:
        return None
    shared = [name for name in theirs if name in ours]
    if not shared:
        return None
    logs = [math.log(ours[name] / theirs[name]) for name in shared]
    better = sum(ours[name] < theirs[name] for name in shared)
    spread = statistics.stdev(logs) / math.sqrt(len(logs)) if len(logs) > 1 else float("nan")
    return math.exp(statistics.fmean(logs)), math.exp(spread), better, len(logs)


def split_half(results: dict, phase: str, groups: tuple[str, ...], labels: list[str], splits: int = 2000,
               seed: int = 0) -> tuple[float, int, int] | None:
    """Whether the models ``labels`` differ by something of their own or by the materials drawn: the
    materials all of them were scored on in ``phase`` split at random into two halves ``splits``
    times, the models ranked on each half by their geometric mean, and the mean Spearman correlation
    of the two rankings (near 1: a model's advantage holds on materials it was not ranked on; near 0:
    it was the draw's). Also the models and materials counted. None for fewer than 3 models, fewer
    than 6 shared materials, or an incomplete unit."""
    per = [per_material(results, phase, groups, label) for label in labels]
    if len(labels) < 3 or any(values is None for values in per):
        return None
    shared = sorted(set.intersection(*(set(v) for v in per)))
    if len(shared) < 6:
        return None
    logs = [[math.log(values[name]) for name in shared] for values in per]
    draw, total, half = random.Random(seed), 0.0, len(shared) // 2
    for _ in range(splits):
        order = list(range(len(shared)))
        draw.shuffle(order)
        a, b = order[:half], order[half:]
        total += spearman([sum(m[i] for i in a) for m in logs], [sum(m[i] for i in b) for m in logs])
    return total / splits, len(labels), len(shared)


def ranks(values: list[float]) -> list[float]:
    """Ranks from 0, ties sharing their mean rank."""
    order = sorted(range(len(values)), key=lambda i: values[i])
    out = [0.0] * len(values)
    i = 0
    while i < len(order):
        j = i
        while j + 1 < len(order) and values[order[j + 1]] == values[order[i]]:
            j += 1
        for k in range(i, j + 1):
            out[order[k]] = (i + j) / 2
        i = j + 1
    return out


def spearman(a: list[float], b: list[float]) -> float:
    """Spearman's rank correlation (Pearson's of the ranks); NaN for fewer than 2 or constant ranks."""
    ra, rb = ranks(a), ranks(b)
    n = len(ra)
    if n < 2:
        return float("nan")
    ma, mb = sum(ra) / n, sum(rb) / n
    cov = sum((x - ma) * (y - mb) for x, y in zip(ra, rb))
    var = math.sqrt(sum((x - ma) ** 2 for x in ra) * sum((y - mb) ** 2 for y in rb))
    return cov / var if var else float("nan")


def columns(results: dict) -> list[tuple[str, str, tuple[str, ...]]]:
    """(heading, phase, groups) of every column with at least one complete cell."""
    out = []
    for phase, (groups, _, _) in PHASES.items():
        for heading, gs in ((f"{phase} zoo", ("zoo",)), (f"{phase} ggx", ("ggx",)), (f"{phase} both", groups)) \
                if len(groups) > 1 else ((phase, groups),):
            if all(g in groups for g in gs) and any(cell(results, phase, gs, label) is not None
                                                    for label, _ in results["models"]):
                out.append((heading, phase, gs))
    return out


def fmt(x: float | None, digits: int = 4) -> str:
    return "—" if x is None or x != x else f"{x:.{digits}f}"


def markdown_section(env: dict, results: dict, command: str, against: str | None = None) -> str:
    """The section from whatever units are complete: never fails on a partial run. ``against``: a
    model's label, to pair every other model with (``paired``)."""
    config, models = results["config"], results["models"]
    cols = columns(results)
    n = {g: len(u["per_material"]) for k, u in results["units"].items() for g in [k.split("|")[1]]}
    lines = [SECTION, "", f"Command: `{command}`  ", machine_line(env), "",
             "Every model scored by `neuenh.selection.fit_score` (modules frozen, each material's parameters fitted "
             "to part of its samples, the mean log-L1 over materials measured on others) on materials it never "
             f"trained on. *zoo* ({n.get('zoo', 0)}) and *ggx* ({n.get('ggx', 0)}): materials of the training "
             f"sources drawn with seeds no search used (synthetic_zoo {config['seed'] + 5}, synthetic_ggx "
             f"{config['seed'] + 4}; *score2*: {config['seed'] + 1005} and {config['seed'] + 1004}); *rgl*: the "
             f"{n.get('rgl', 0) or 'unmeasured'} visible RGL materials, a final check only; *merl* "
             f"({n.get('merl', 0)}): the NBRDF stand-ins `{config.get('merl_spec', '—')}` holds out. *score* phases: the search's budget "
             f"({SEARCH.fit_samples} fit / {SEARCH.test_samples} test samples, {SEARCH.epochs} epochs, "
             f"{SEARCH.near_mirror:.0%} near the mirror); *user* phases: `neuenh fit`'s ({USER.fit_samples} / "
             f"{USER.test_samples}, {USER.epochs} epochs, {USER.near_mirror:.0%} near the mirror). *val*: the "
             "in-sample validation loss the model's search selected by. —: not measured (run cut short).", ""]
    lines += ["| model | val |" + "".join(f" {h} |" for h, _, _ in cols), "|---|---:|" + "---:|" * len(cols)]
    for label, val in models:
        lines.append(f"| `{label}` | {fmt(val, 5)} |" + "".join(f" {fmt(cell(results, p, gs, label))} |" for _, p, gs in cols))
    seen = results.get("merl_seen", {})  # models not scored on the held-out MERL materials, by design
    for label, names in seen.items():
        lines.append(f"`{label}` trained on {len(names)} of the held-out MERL materials: not scored on them.")
    if against is not None:
        lines += ["", (f"Paired against `{against}`: the geometric mean of each model's per-material ratio to it (× or ÷ "
                       "its standard error), and on how many of the materials both were scored on the model is lower."), "",
                  "| model |" + "".join(f" {h} |" for h, _, _ in cols), "|---|" + "---:|" * len(cols)]
        for label, _ in models:
            if label == against:
                continue
            cells = [paired(results, p, gs, label, against) for _, p, gs in cols]
            lines.append(f"| `{label}` |" + "".join(
                " — |" if c is None else f" {c[0]:.3f} (×/ {c[1]:.3f}), {c[2]} of {c[3]} |" for c in cells))
        enhanced = [label for label, _ in models if label != "ggx"]
        halves = [(h, split_half(results, p, gs, [x for x in enhanced if "merl" not in gs or x not in seen]))
                  for h, p, gs in cols]
        if any(r is not None for _, r in halves):
            measured = [f"{h} {r[0]:.2f} ({r[1]} models, {r[2]} materials)" for h, r in halves if r is not None]
            lines += ["", "Do the enhanced models' differences hold across materials? Their ranking on one random "
                      "half of a column's materials against their ranking on the other half, Spearman's correlation "
                      "averaged over 2,000 splits (near 1: a model's advantage is its own; near 0: it was the "
                      "materials drawn): " + "; ".join(measured) + "."]
    selectors = [(h, p, gs) for h, p, gs in cols if p in ("score", "score2") and len(gs) > 1]
    truths = [(h, p, gs) for h, p, gs in cols if p not in ("score", "score2") or (p == "score2" and len(gs) > 1)]
    for what, subset in ((f"the rungs of `{config['model']}` (one search, one training set)",
                          [(label, val) for label, val in models if label.startswith(config["model"] + "@")]),
                         ("every enhanced model", [(label, val) for label, val in models if label != "ggx"])):
        if len(subset) < 3 or not truths:
            continue
        lines += ["", f"Spearman rank correlation over {what}, {len(subset)} models, of the score each row selects by "
                  "with each column's held-out error (1: the same order; —: incomplete; a model that trained on a "
                  "column's materials is left out of it, and the cell then says how many models it ranks):", "",
                  "| selected by | " + " | ".join(h for h, _, _ in truths) + " |", "|---|" + "---:|" * len(truths)]
        for name, score in [("val (in-sample)", dict(subset))] + [
                (h, {label: cell(results, p, gs, label) for label, _ in subset}) for h, p, gs in selectors]:
            cells = []
            for _, p, gs in truths:
                ranked = [label for label, _ in subset if "merl" not in gs or label not in seen]
                truth = {label: cell(results, p, gs, label) for label in ranked}
                complete = len(ranked) >= 3 and all(score[k] is not None and truth[k] is not None for k in ranked)
                value = fmt(spearman([score[k] for k in ranked], [truth[k] for k in ranked]), 2) if complete else "—"
                cells.append(value if len(ranked) == len(subset) else f"{value} ({len(ranked)} models)")
            lines.append(f"| {name} | " + " | ".join(cells) + " |")
    walls = [(u["wall_s"], len(u["per_material"])) for k, u in results["units"].items()
             if k.split("|")[0] in ("score", "score2") and not k.endswith("|ggx")]
    if walls:
        per = statistics.median(w / m for w, m in walls)
        lines += ["", f"Price of the score (one torch thread, this shared machine): median {per:.2f} s per held-out "
                  f"material and enhanced candidate at the search's budget, so {per * 16:.0f} s a candidate for "
                  "examples/reference-fit.yaml's 16 held-out materials."]
    return "\n".join(lines) + "\n"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--model", default="enhanced-ggx")
    parser.add_argument("--rungs", choices=("all", "final"), default="all", help="--model's rungs to score")
    parser.add_argument("--extra", action="append", default=[], help="NAME=BUNDLE_DIR, a further model to score")
    parser.add_argument("--search", help="a `neuenh search --data-dir` folder: score each committed round's winner")
    parser.add_argument("--zoo", type=int, default=16)
    parser.add_argument("--ggx", type=int, default=8)
    parser.add_argument("--seed", type=int, default=1000)
    parser.add_argument("--rgl", type=Path, default=RGL)
    parser.add_argument("--merl-spec", type=Path,
                        help="the merl-user and merl-auto phases: the NBRDF stand-ins this spec holds out")
    parser.add_argument("--phases", nargs="+", choices=tuple(PHASES), default=list(PHASES))
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--json", type=Path, required=True, help="results, written as units finish; resumed from")
    parser.add_argument("--report-only", action="store_true", help="write the section from --json, run nothing")
    parser.add_argument("--against", metavar="LABEL", help="a scored model's label (as the table names it): every "
                        "other model's per-material ratios to it, paired")
    parser.add_argument("--write")
    args = parser.parse_args()
    extras = {}
    for e in args.extra:
        name, sep, path = e.partition("=")
        if not sep or not name or not Path(path).is_dir():
            parser.error(f"--extra {e!r}: expected NAME=BUNDLE_DIR with an existing folder")
        extras[name] = path
    if args.merl_spec is None and (merl := merl_phases(args.phases)):
        if args.phases != list(PHASES):
            parser.error(f"--phases {' '.join(merl)} needs --merl-spec SPEC.yaml (the spec whose nbrdf source holds "
                         "them out)")
        args.phases = [phase for phase in args.phases if phase not in merl]
    if args.search and not (Path(args.search) / "jobs.sqlite").is_file():
        parser.error(f"--search {args.search}: no jobs.sqlite there (a `neuenh search --data-dir` folder)")
    config = {"model": args.model, "extras": extras, "zoo": args.zoo, "ggx": args.ggx, "seed": args.seed,
              "score_budget": [SEARCH.fit_samples, SEARCH.test_samples, SEARCH.epochs],  # a changed spec: units anew
              "starts": "training materials",  # not resumed from a file of the mean-only starts (``contenders``)
              **({"search": str(Path(args.search).resolve())} if args.search else {}),
              **({"merl_spec": str(args.merl_spec.resolve())} if args.merl_spec else {}),
              **({"rungs": args.rungs} if args.rungs != "all" else {})}
    env = machine()
    if args.report_only:
        if not args.json.exists():
            parser.error(f"--report-only: {args.json} does not exist")
        results = json.loads(args.json.read_text())
        check_against(args.against, [label for label, _ in results["models"]])  # a run checks before scoring
    else:
        results = run(args, config)
    command = "python bench/bench_selection.py " + " ".join(a for a in sys.argv[1:] if a != "--report-only")
    publish(markdown_section(env, results, command, args.against), args.write, SECTION)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
