"""What ``neuenh scene plan`` writes for a plan (``planner.Plan``), each file atomically:

* ``plan.json`` — the scene, the ladder with each rung's measured cost, per material the chosen
  rung (model, state, fitted parameters, error, cost) and the richest rung's error and cost, every
  rung's results, and the frame totals;
* ``bundles/<source>/`` — per searched model the plan draws rungs from, a bundle holding only the
  rungs the plan uses (their modules' weights; ``neuenh.checkpoint.Rung``), its top model the richest
  of them; analytical and NBRDF rungs need none (their parameters are in ``plan.json``);
* ``plan.md`` — the table per material and the scene totals: the weighted frame cost and error of
  the plan against the richest rung everywhere and the cheapest rung everywhere;
* ``cost_vs_error.png`` — frame cost against frame error for the three, and each material's rungs;
* ``contact_sheet.png`` — every material that can be rendered on the ball: its measured truth beside
  the rung chosen for it.
"""

from __future__ import annotations

import io
import json
from dataclasses import dataclass
from pathlib import Path

from ..capacities import ANALYTICAL_CAPACITIES
from ..files import atomic_write
from .planner import Plan

__all__ = ["PlanModels", "plan_models", "safe_name", "write_plan"]

PLAN_JSON, PLAN_MD, PLOT, SHEET = "plan.json", "plan.md", "cost_vs_error.png", "contact_sheet.png"


def write_plan(plan: Plan, out: Path, *, sheet: bool = True) -> list[Path]:
    out.mkdir(parents=True, exist_ok=True)
    written = [atomic_write(out / PLAN_JSON, json.dumps(plan.to_json(), indent=1) + "\n")]
    written += _bundles(plan, out / "bundles")
    _plot(plan, out / PLOT)
    written.append(out / PLOT)
    if sheet and any(m.renderable for m in plan.sources):
        _contact_sheet(plan, out / SHEET)
        written.append(out / SHEET)
    written.append(atomic_write(out / PLAN_MD, markdown(plan, sheet=(out / SHEET).exists())))
    return written


# -- bundles ------------------------------------------------------------------------------------
def _bundles(plan: Plan, folder: Path) -> list[Path]:
    """Per source model, a bundle of the used rungs that have modules (module doc)."""
    from ..checkpoint import Bundle, Rung

    used = {m.chosen for m in plan.materials}
    by_source: dict[str, list] = {}
    for rung in plan.rungs:
        model = getattr(rung, "model", None)
        if rung.key in used and model is not None and model.n_weights():
            by_source.setdefault(rung.source, []).append(rung)
    written = []
    for source, rungs in by_source.items():
        top = max(rungs, key=lambda r: (r.shared_weights, r.round if r.round is not None else -1))
        bundle = Bundle(top.model, provenance={"scene_plan": {"scene": plan.scene.name, "source": source}},
                        rungs=[Rung(r.round if r.round is not None else -1,
                                    r.val_loss if r.val_loss is not None else float("nan"), r.model,
                                    None if r.trained is None else r.trained.latent_codes())
                               for r in rungs])
        written.append(bundle.save(folder / safe_name(source)))
    return written


@dataclass(frozen=True)
class PlanModels:
    """What the exporters take from a written plan (``plan_models``)."""

    groups: list[tuple[str, object, dict]]  # (rung key, BRDFModel, {material: MaterialParams}), in ladder order
    nbrdf: dict[str, object]  # material -> its NBRDFNetwork, for those planned with the per-material NBRDF rung


def plan_models(plan_json: Path) -> PlanModels:
    """The models a written plan uses, each with its materials' records, read from ``plan.json`` and
    the bundles beside it (what the exporters take, ``neuenh export --plan``). The materials planned
    with the NBRDF rung are not in ``groups`` but in ``PlanModels.nbrdf``, each with its network (its
    weights are in ``plan.json``). A rung whose bundle is missing is a ValueError naming it."""
    from ..checkpoint import Bundle, BundleError
    from ..materials import MaterialParams
    from ..models import get_model
    from ..study.nbrdf_fit import NBRDFNetwork

    try:
        plan = json.loads(Path(plan_json).read_text())
        ladder = {r["key"]: r for r in plan["ladder"]}
        chosen = [(m["name"], m["chosen"], m["params"]) for m in plan["materials"]]
    except FileNotFoundError:
        raise ValueError(f"{plan_json}: no such file") from None
    except IsADirectoryError:  # the plan's folder: its plan.json is inside
        raise ValueError(f"{plan_json}: a folder, not a scene plan (give its plan.json)") from None
    except (ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"{plan_json}: not a scene plan (neuenh scene plan): {type(exc).__name__}: {exc}") from None
    out: dict[str, tuple[object, dict]] = {}
    nbrdf = {}
    for name, key, params in chosen:
        rung = ladder[key]
        if rung["model"] == "nbrdf":
            try:
                nbrdf[name] = NBRDFNetwork.from_state(params)
            except ValueError as exc:
                raise ValueError(f"{plan_json}: material {name!r}: {exc}") from None
            continue
        if key not in out:
            if rung["shared_weights"]:
                folder = Path(plan_json).parent / "bundles" / safe_name(rung["source"])
                try:
                    bundle = Bundle.load(folder)
                except BundleError as exc:
                    raise ValueError(f"{plan_json}: rung {rung['label']!r} needs its bundle: {exc}") from None
                model = next((r.model for r in bundle.rungs if r.state == rung["state"]), None)
                if model is None:
                    raise ValueError(f"{folder}: holds no rung in state {rung['state']} (plan.json's {rung['label']!r})")
            else:
                model = get_model(rung["model"], state=rung["state"], alternatives=rung.get("alternatives", False))
            out[key] = (model, {})
        try:
            out[key][1][name] = MaterialParams.from_json(params)
        except ValueError as exc:
            raise ValueError(f"{plan_json}: material {name!r}: {exc}") from None
    return PlanModels([(key, model, materials) for key, (model, materials) in out.items()], nbrdf)


def safe_name(name: str) -> str:
    """A rung key or model source as a folder name."""
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in Path(name).name) or "model"


# -- the document --------------------------------------------------------------------------------
def markdown(plan: Plan, sheet: bool = True) -> str:
    s, totals = plan.scene, plan.totals()
    tol = s.tolerance
    within = f"within {100 * tol.relative:g} % of the best rung" if tol.relative is not None \
        else f"at most {tol.absolute:g}"
    metric = {"log_l1": "held-out log-L1", "delta_e_itp": "ΔE_ITP of the render", "ssim": "1 − SSIM of the render"}[
        tol.metric]
    analytical = sum(1 for m in plan.materials if _analytical(plan.rung_info(m.chosen), m.result(m.chosen).params))
    per_rung = totals["plan"]["rungs"]  # rung key -> materials the planner gave it
    lines = [
        f"# Scene plan{f': {s.name}' if s.name else ''}", "",
        f"Every material gets the cheapest rung of the ladder whose {metric} is {within} "
        f"(fit on {s.fit.samples} measurements, tested on {s.fit.test_samples} others; "
        f"{100 * s.fit.near_mirror:g} % of a continuous material's pairs near the mirror direction). "
        "Cost: nanoseconds per evaluation of the rung's specialized BRDF, measured on this machine (one thread).",
        "", f"**{analytical} of {len(plan.materials)} materials stay analytical"
        + "".join(f"; {per_rung.get(r['key'], 0)} of {len(plan.materials)} go to {r['label']}" for r in plan.ladder
                  if r["model"] == "nbrdf")
        + ".** The ladder's last column counts the materials given to each rung.", "",
        "## Ladder", "", "| rung | model | shared weights | cost (ns / evaluation) | materials given to it |",
        "|---|---|---:|---:|---:|",
    ]
    lines += [f"| {r['label']} | {r['model']} {r['state'] or ''} | {r['shared_weights']:,} | {r['cost_ns']:.1f} | "
              f"{per_rung.get(r['key'], 0)} |" for r in plan.ladder]
    richest = plan.ladder[-1]["key"]
    lines += ["", "## Materials", "",
              "| material | weight | chosen rung | error | cost (ns) | parameters (bytes) | richest rung's error | "
              "its cost (ns) |", "|---|---:|---|---:|---:|---:|---:|---:|"]
    for m in plan.materials:
        info, chosen, top = plan.rung_info(m.chosen), m.result(m.chosen), m.result(richest)
        lines.append(f"| {m.name} | {m.weight:g} | {info['label']} | {chosen.error:.4f} | {info['cost_ns']:.1f} | "
                     f"{chosen.param_bytes} | {top.error:.4f} | {plan.rung_info(richest)['cost_ns']:.1f} |")
    lines += ["", "## Scene totals (weighted by each material's weight)", "",
              "| | frame cost (ns / evaluation) | frame error | held-out log-L1 | parameters (bytes) |",
              "|---|---:|---:|---:|---:|"]
    names = {"plan": "**the plan**", "richest": f"richest rung everywhere ({plan.ladder[-1]['label']})",
             "cheapest": f"cheapest rung everywhere ({plan.ladder[0]['label']})"}
    for key, label in names.items():
        t = totals[key]
        lines.append(f"| {label} | {t['cost_ns']:.1f} | {t['error']:.4f} | {t['heldout_log_l1']:.4f} | "
                     f"{t['param_bytes']} |")
    p, r = totals["plan"], totals["richest"]
    lines += ["", f"The plan costs {p['cost_ns'] / r['cost_ns']:.2f}× the richest rung everywhere per evaluation, "
              f"at {p['error'] / r['error']:.2f}× its frame error.", "", f"![frame cost against error]({PLOT})"]
    if sheet:
        lines += ["", f"![each material: measured truth, then the chosen rung]({SHEET})"]
    return "\n".join(lines) + "\n"


def _analytical(rung: dict, params: dict) -> bool:
    """Whether a material's chosen rung evaluates it analytically: an analytical rung, or a rung with
    modules that fitted it at an analytical capacity (``capacities.ANALYTICAL_CAPACITIES``)."""
    if rung["model"] == "nbrdf":
        return False
    return rung["shared_weights"] == 0 or params.get("capacity") in ANALYTICAL_CAPACITIES


# -- figures ---------------------------------------------------------------------------------------
def _plot(plan: Plan, path: Path) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    totals = plan.totals()
    fig = Figure(figsize=(6.4, 4.4), dpi=110)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    for m in plan.materials:  # each material's rungs, faint, cheapest first
        points = sorted((plan.rung_info(r.rung)["cost_ns"], r.error) for r in m.results)
        ax.plot([x for x, _ in points], [y for _, y in points], "-", color="0.85", lw=0.8, zorder=1)
    styles = {"cheapest": ("s", "tab:blue"), "richest": ("^", "tab:red"), "plan": ("o", "tab:green")}
    labels = {"plan": "the plan", "richest": "richest everywhere", "cheapest": "cheapest everywhere"}
    for key, (marker, colour) in styles.items():
        t = totals[key]
        ax.scatter([t["cost_ns"]], [t["error"]], marker=marker, s=80, color=colour, label=labels[key], zorder=3)
    ax.set_xlabel("frame cost (ns per BRDF evaluation, weighted)")
    ax.set_ylabel(f"frame error ({plan.scene.tolerance.metric}, weighted)")
    ax.set_title("Scene: cost against error (grey: each material's rungs)")
    ax.legend(loc="best", frameon=False)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    _save(fig, path)


def _contact_sheet(plan: Plan, path: Path) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from ..render import render
    from ..render.output import tonemap
    from ..study.comparison import RenderSetup

    r = plan.scene.render
    setup = RenderSetup(r.size, r.samples_per_axis, r.seed, r.scene)
    scene, lights = setup.build_scene(), setup.lights()
    rows = [(src, m) for src, m in zip(plan.sources, plan.materials) if src.renderable]
    fig = Figure(figsize=(4.2, 2.2 * len(rows) + 0.3), dpi=100)
    FigureCanvasAgg(fig)
    for i, (src, m) in enumerate(rows):
        truth = render(lambda wi, wo: src.material.evaluate(wi, wo).float(), scene, lights)
        chosen = render(plan.rung(m.chosen).brdf_of(m.result(m.chosen).params), scene, lights)
        for j, (image, title) in enumerate([(truth, f"{m.name}\nmeasured"),
                                            (chosen, f"{plan.rung_info(m.chosen)['label'][:28]}\n"
                                                     f"error {m.result(m.chosen).error:.4f}")]):
            ax = fig.add_subplot(len(rows), 2, 2 * i + j + 1)
            ax.imshow(tonemap(image))
            ax.set_title(title, fontsize=7)
            ax.axis("off")
    fig.tight_layout()
    _save(fig, path)


def _save(fig, path: Path) -> Path:
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png")
    return atomic_write(path, buffer.getvalue())

