"""The scene planner on scenes whose answer is known: a material that plain GGX generated stays
analytical, a material GGX cannot represent climbs the ladder; the tolerance and the weights are
respected, plans reproduce, an interrupted plan resumes (tests/cli/test_scene_cli.py), and a bad scene is one line naming it.

The ladder is [ggx, nbrdf] (a per-material network surely beats GGX on a retro-reflective material,
and GGX is exact on its own), so the expected choices do not hang on a trained model."""

from __future__ import annotations

from pathlib import Path

import pytest

from neuenh.scene import SceneError, parse_scene, plan_scene
from neuenh.scene.ladder import GraphRung
from neuenh.scene.planner import RungResult, choose, load_materials
from neuenh.scene.spec import Tolerance
from scene_files import scene, write_tables


@pytest.fixture(scope="module")
def tables(tmp_path_factory) -> Path:
    return write_tables(tmp_path_factory.mktemp("scene"))


@pytest.fixture(scope="module")
def known_plan(tables):
    return plan_scene(parse_scene(scene(tables)), tables)


def test_the_ggx_material_stays_analytical_and_the_retro_one_climbs(known_plan):
    chosen = {m.name: m.chosen for m in known_plan.materials}
    assert chosen == {"gloss": "ggx", "retro": "nbrdf"}
    gloss, retro = known_plan.materials
    assert gloss.result("ggx").error < 1e-3  # GGX is exact on its own material (float32 table)
    assert retro.result("nbrdf").error < 0.75 * retro.result("ggx").error


def test_the_tolerance_is_respected_and_the_weights_make_the_totals(known_plan):
    for m in known_plan.materials:
        best = min(r.error for r in m.results)
        assert m.result(m.chosen).error <= best * 1.1 + 1e-12
    totals = known_plan.totals()
    costs = {r["key"]: r["cost_ns"] for r in known_plan.ladder}
    gloss, retro = known_plan.materials
    assert totals["plan"]["error"] == pytest.approx((3 * gloss.result("ggx").error + retro.result("nbrdf").error) / 4)
    assert totals["plan"]["cost_ns"] == pytest.approx((3 * costs["ggx"] + costs["nbrdf"]) / 4)
    assert totals["richest"]["rungs"] == {"nbrdf": 2} and totals["cheapest"]["rungs"] == {"ggx": 2}
    # Costs are measured timings, so which rung is cheaper is the machine's answer, not the test's:
    # the plan mixes 3 parts GGX with 1 part NBRDF, so it is cheaper than all-NBRDF exactly when GGX is.
    assert (totals["plan"]["cost_ns"] < totals["richest"]["cost_ns"]) == (costs["ggx"] < costs["nbrdf"])
    assert totals["plan"]["error"] < totals["cheapest"]["error"]
    assert totals["plan"]["param_bytes"] == 4 * (12 + 675)


def test_the_same_scene_plans_the_same(tables, known_plan):
    again = plan_scene(parse_scene(scene(tables)), tables)
    for a, b in zip(known_plan.materials, again.materials):
        assert a.chosen == b.chosen and [r.error for r in a.results] == [r.error for r in b.results]


def test_an_absolute_tolerance_takes_the_cheapest_rung_within_it_or_the_best():
    results = [RungResult("a", 0.05, 0.05, 0.0, 12, 48, {}), RungResult("b", 0.02, 0.02, 0.0, 39, 156, {}),
               RungResult("c", 0.01, 0.01, 0.0, 675, 2700, {})]
    costs = {"a": 100.0, "b": 250.0, "c": 260.0}
    assert choose(results, costs, Tolerance(absolute=0.06)) == "a"
    assert choose(results, costs, Tolerance(absolute=0.03)) == "b"
    assert choose(results, costs, Tolerance(absolute=0.001)) == "c"  # none within: the best
    assert choose(results, costs, Tolerance(relative=1.5)) == "b"  # 0.02 <= 0.01 * 2.5, 0.05 is not
    # a later rung only when clearly cheaper: c at 95 % of b's cost is within the margin, so b stays
    assert choose(results, {"a": 100.0, "b": 250.0, "c": 240.0}, Tolerance(relative=1.5)) == "b"
    assert choose(results, {"a": 100.0, "b": 250.0, "c": 200.0}, Tolerance(relative=1.5)) == "c"


def test_rungs_of_a_searched_model_join_the_ladder(tmp_path, tables):
    from neuenh.checkpoint import Bundle, Rung

    bundle = Bundle.initial("ggx", ["a"])
    plain = Bundle(bundle.model, bundle.materials)
    bundle.model = bundle.model.enhance("00000100000", seed=1)
    bundle.rungs = [Rung.of(0, 0.03, plain), Rung.of(1, 0.02, bundle)]
    bundle.save(tmp_path / "searched")
    spec = parse_scene(scene(tables, materials=[{"path": str(tables / "gloss.npz")}],
                             ladder=[{"rungs": str(tmp_path / "searched")}]))
    plan = plan_scene(spec, tables)
    assert [r["state"] for r in plan.ladder] == ["00000000000", "00000100000"]
    assert [r["shared_weights"] > 0 for r in plan.ladder] == [False, True]
    assert isinstance(plan.rungs[1], GraphRung) and plan.rungs[1].round == 1


def test_a_model_at_a_capacity_of_its_own_is_a_rung_and_an_analytical_capacity_stays_analytical(tmp_path, tables):
    """``{model: M, capacity: original}`` fits plain GGX in the module's place: exact on GGX's own
    material (the module, random here, cannot be), and counted as analytical in plan.md."""
    from neuenh.scene.outputs import write_plan
    from scene_files import write_module_bundle

    write_module_bundle(tmp_path / "searched")
    spec = parse_scene(scene(tables, materials=[{"path": "gloss.npz"}],
                             ladder=[{"model": str(tmp_path / "searched"), "capacity": "original"}]))
    plan = plan_scene(spec, tables)
    [rung] = plan.ladder
    assert rung["key"] == f"{tmp_path / 'searched'}:original" and rung["capacity"] == "original"
    [gloss] = plan.materials
    result = gloss.result(rung["key"])
    assert result.params["capacity"] == "original" and result.n_params == 12 and result.error < 1e-3
    write_plan(plan, tmp_path / "plan", sheet=False)
    assert "**1 of 1 materials stay analytical." in (tmp_path / "plan" / "plan.md").read_text()


def test_a_ladders_model_and_its_rungs_start_their_fits_where_neuenh_fit_does(tmp_path, tables):
    """A named model and every rung of ``{rungs: M}`` fit with their training materials' codes (their
    mean and the codes that fit a material best: ``LatentAdam``'s starts), the model itself as ``neuenh
    fit`` does; an earlier rung of a bundle written before stop 57, which kept only their mean, from that mean."""
    import torch

    from neuenh.checkpoint import Bundle, Rung
    from neuenh.data.table import load_table
    from neuenh.fit import FitOptions, fit_materials
    from neuenh.materials import MaterialTable
    from neuenh.scene.ladder import build_ladder

    bundle = Bundle.initial("ggx", [f"trained{i}" for i in range(6)])
    bundle.model = bundle.model.enhance("00000100000", seed=1)
    with torch.no_grad():  # codes far apart, so that the best of them is not their mean
        bundle.materials.latent.copy_(torch.rand(bundle.materials.latent.shape, generator=torch.Generator().manual_seed(0)))
    mean_only = Rung(0, 0.04, bundle.model, bundle.materials.mean_latent()[None])
    bundle.rungs = [mean_only, Rung.of(1, 0.03, bundle), Rung.of(2, 0.02, bundle)]
    bundle.save(tmp_path / "searched")
    spec = parse_scene(scene(tables, ladder=[str(tmp_path / "searched"), {"rungs": str(tmp_path / "searched")}]))
    named, *laddered = build_ladder(spec.ladder)
    samples = load_table(tables / "retro.npz").samples
    options = FitOptions(capacity="latent", epochs=8)
    model, trained = bundle.model, Bundle.load(tmp_path / "searched").materials
    mean = MaterialTable(model.specs, ["mean"], model.latent_dim, latent=trained.mean_latent().reshape(1, -1))
    as_neuenh_fit, from_the_mean = (fit_materials(model, samples, options.protocol_for(model), seed=0, trained=t).losses
                                    for t in (trained, mean))
    assert as_neuenh_fit != from_the_mean, "the training codes made no difference: the test cannot tell the starts apart"
    assert [[f.fit_loss for f in rung.fit(samples, options, 0)] for rung in (named, *laddered)] == \
        [as_neuenh_fit, from_the_mean, as_neuenh_fit, as_neuenh_fit]


@pytest.mark.parametrize("changes, message", [
    ({"materials": [{"path": "nowhere.npz"}]}, "materials.0: .*nowhere.npz"),
    ({"ladder": ["phong"]}, r"ladder.0 'phong' is neither an analytical model"),
    ({"ladder": []}, "ladder: List should have at least 1 item"),
    ({"materials": [{"path": "gloss.npz", "weight": -1}]}, "materials.0.*weight: Input should be greater than"),
    ({"tolerance": {"metric": "ssim", "relative": 0.1}}, "tolerance.metric ssim renders .* use metric log_l1"),
    ({"tolerance": {"relative": 0.1, "absolute": 1}}, "exactly one of 'relative'"),
    ({"materials": [{"path": "gloss.npz"}, {"path": "gloss.npz"}]}, "gloss more than once"),
    ({"materials": [{"path": "gloss.npz", "sha256": "0" * 64}]},
     r"materials.0: .*gloss.npz: its content does not match its sha256 000000000000\.\.\. \(damaged or replaced\)"),
    ({"materials": [{"path": "gloss.npz", "sha256": "abc"}]}, "materials.0.*sha256: String should match pattern"),
    ({"ladder": ["ggx", {"model": "ggx", "capacity": "most"}]},
     r"^scene: ladder.1.model.capacity: .*unknown capacity 'most'"),
    ({"ladder": [{"model": "ggx", "rung": 1}]}, r"^scene: ladder.0.model.rung: Extra inputs are not permitted$"),
    ({"ladder": [{"state": "0"}]}, r"^scene: ladder.0: a ladder entry is a model's name, \{rungs: MODEL\} or"),
], ids=["missing-file", "unknown-model", "empty-ladder", "negative-weight", "render-metric-on-a-table",
        "two-tolerances", "same-name", "damaged-file", "not-a-digest", "unknown-capacity", "extra-field",
        "unknown-entry"])
def test_bad_scenes_are_one_line_naming_the_problem(tables, changes, message):
    with pytest.raises(SceneError, match=message) as info:
        plan_scene(parse_scene(scene(tables, **changes)), tables)
    assert "\n" not in str(info.value)


def test_a_file_whose_digest_matches_is_read(tables):
    import hashlib

    digest = hashlib.sha256((tables / "gloss.npz").read_bytes()).hexdigest()
    materials = load_materials(parse_scene(scene(tables, materials=[{"path": "gloss.npz", "sha256": digest}])), tables)
    assert [m.name for m in materials] == ["gloss"]


def test_the_example_scene_is_valid_and_names_files_beside_it():
    from neuenh.scene import load_scene

    spec, base = load_scene(Path(__file__).resolve().parents[3] / "examples" / "scene.yaml")
    assert len(spec.materials) == 8 and spec.tolerance.relative == 0.1
    assert all((base / m.path).resolve().name.endswith("_rgb.bsdf") for m in spec.materials)


def test_a_plan_with_nbrdf_writes_its_files_counts_each_rung_and_reads_back_its_network(known_plan, tmp_path):
    import torch

    from neuenh.scene.ladder import NBRDFRung
    from neuenh.scene.outputs import plan_models, write_plan

    write_plan(known_plan, tmp_path)
    text = (tmp_path / "plan.md").read_text()
    assert "**1 of 2 materials stay analytical; 1 of 2 go to NBRDF (per material).**" in text
    rows = {line.split(" | ")[0].lstrip("| "): line.rstrip(" |").rsplit(" | ", 1)[1]
            for line in text.splitlines() if line.startswith("| ggx |") or line.startswith("| NBRDF")}
    assert rows == {"ggx": "1", "NBRDF (per material)": "1"}  # the ladder's count of materials given to each rung
    assert not (tmp_path / "bundles").exists()  # neither rung has modules
    planned = plan_models(tmp_path / "plan.json")
    assert list(planned.nbrdf) == ["retro"]
    wi, wo = (torch.nn.functional.normalize(torch.rand(256, 3) + 0.05, dim=1) for _ in range(2))
    fitted = [m for m in known_plan.materials if m.name == "retro"][0].result("nbrdf")
    assert torch.equal(planned.nbrdf["retro"].evaluate(wi, wo), NBRDFRung().brdf_of(fitted.params)(wi, wo))
    [(key, model, materials)] = planned.groups
    assert key == "ggx" and list(materials) == ["gloss"] and not model.has_modules


def test_rung_costs_are_measured_side_by_side_in_rounds_and_keep_each_rungs_fastest():
    import itertools

    import torch

    from neuenh.scene.ladder import rung_costs

    calls = []

    def timed(key, work):
        def brdf(wi, wo):
            calls.append(key)
            return torch.stack([wi] * work).sum(0)  # more work per evaluation: a dearer rung
        return brdf

    costs = rung_costs({"cheap": timed("cheap", 1), "dear": timed("dear", 64)}, rounds=3)
    assert [k for k, _ in itertools.groupby(calls)] == ["cheap", "dear"] * 3  # interleaved, not one after the other
    assert set(costs) == {"cheap", "dear"} and 0 < costs["cheap"] < costs["dear"]
