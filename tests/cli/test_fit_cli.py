"""``neuenh fit`` as a user runs it (a subprocess, and in-process where its output is what is checked:
``tests/cli_runs.py``): exit codes, JSON, one-line errors."""

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from neuenh.checkpoint import Bundle
from neuenh.data.synthetic import synthetic_ggx
from neuenh.data.table import write_table
from neuenh.fit.jit import available as jit_available
from cli_runs import neuenh, neuenh_here, neuenh_on_a_terminal
from ggx_states import PAPER_STATE


@pytest.fixture(scope="module")
def table(tmp_path_factory):
    (material,) = synthetic_ggx(1, seed=8, noise_sigma=0.0)
    wi, wo, f = material.samples(3000, seed=0)
    return write_table(tmp_path_factory.mktemp("t") / "steel.npz", wi, wo, f)


def test_fit_prints_json_and_writes_a_bundle(table, tmp_path):
    out = neuenh("fit", "--model", "ggx", table, "--epochs", "60", "--json", "-o", tmp_path / "b")
    assert out.returncode == 0, out.stderr
    assert out.stderr == "", "progress on a pipe: it is for a person at a terminal (test_jobs_fit_...)"
    report = json.loads(out.stdout)
    (material,) = report["materials"]
    assert material["name"] == "steel" and material["loss"] < 0.05
    assert set(material["params"]) == {"normal", "t_theta", "rho_d", "rho_s", "alpha_x", "alpha_y", "f0"}
    assert (material["latent"], material["capacity"], material["params_per_material"]) == (None, "analytical", 12)
    bundle = Bundle.load(tmp_path / "b")
    assert bundle.materials.names == ("steel",) and bundle.model.name == "ggx"


def test_fit_with_a_bundle_directory(table, tmp_path):
    from neuenh.models import get_model

    Bundle(get_model("ggx", state=PAPER_STATE, seed=0)).save(tmp_path / "enh")
    out = neuenh_here("fit", "--model", tmp_path / "enh", table, "--capacity", "latent", "--epochs", "3", "--json")
    assert out.returncode == 0, out.stderr
    report = json.loads(out.stdout)
    (material,) = report["materials"]
    assert report["state"] == PAPER_STATE and len(material["latent"]) == 27 and "latent" not in material["params"]
    assert (material["capacity"], material["params_per_material"], material["corrections"]) == ("latent", 39, {})


def test_the_default_capacity_auto_reports_each_materials_choice_and_a_bundle_keeps_it(tmp_path):
    """``--capacity auto``, the default, on a GGX material with an untrained model: the analytical capacity wins
    the cross-validation (the random modules fit nothing better), the report says so with its
    count; ``-o`` writes it into the model's bundle with its capacity, and the bundle's material
    renders as the analytical model (here plain GGX) with its parameters, not through the random
    modules."""
    from neuenh.data.directions import sample_directions
    from neuenh.models import get_model
    from neuenh.render import bundle_brdf

    (material,) = synthetic_ggx(1, seed=8, noise_sigma=0.0)
    small = write_table(tmp_path / "steel.npz", *material.samples(150, seed=0))
    Bundle(get_model("ggx", state=PAPER_STATE, seed=0)).save(tmp_path / "enh")
    args = ("fit", "--model", tmp_path / "enh", small, "--epochs", "4",
            "--lbfgs-iterations", "20", "--json")
    out = neuenh_here(*args)
    assert out.returncode == 0, out.stderr
    report = json.loads(out.stdout)
    (fitted,) = report["materials"]
    assert report["protocol"]["name"] == "adaptive"
    assert (fitted["capacity"], fitted["latent"], fitted["params_per_material"]) == ("analytical", None, 12)
    out = neuenh_here(*args, "-o", tmp_path / "b")
    assert out.returncode == 0, out.stderr
    bundle = Bundle.load(tmp_path / "b")
    assert bundle.materials.as_params(0).capacity == "analytical" and bundle.materials.coded() == []
    wi, wo = (w.float() for w in sample_directions(300, seed=1))
    ggx = get_model("ggx")
    want = ggx.evaluate(wi, wo, ggx.used_params(bundle.materials.as_params(0)))
    # the same formula in float32 by two paths agrees to ~1e-6; the random modules would be off by O(1)
    torch.testing.assert_close(bundle_brdf(bundle, 0)(wi, wo), want, rtol=1e-3, atol=1e-6)


SHIPPED = Path(__file__).resolve().parents[2] / "models" / "enhanced-ggx" / "model.json"


@pytest.mark.skipif(not SHIPPED.exists(), reason="no shipped model in this tree")
def test_fit_with_the_shipped_enhanced_ggx_out_of_the_box(table, tmp_path):
    """``--model enhanced-ggx`` works out of the box and models only what the material needs: at the
    default capacity (auto) a noiseless GGX material validates best as the model the search started
    from, plain GGX (12 parameters; the latent fit of its 42 ends near 2.6e-3, the modules' own
    error), and L-BFGS fits that nearly exactly (~2e-5 in 60 iterations, ~1e-6 in 300) rather than to the
    1e-3 bound."""
    out = neuenh_here("fit", "--model", "enhanced-ggx", table, "--epochs", "30", "--lbfgs-iterations", "60", "--json")
    assert out.returncode == 0, out.stderr
    report = json.loads(out.stdout)
    (material,) = report["materials"]
    assert report["state"] != "0" * 11 and report["protocol"]["name"] == "adaptive"
    assert (material["capacity"], material["latent"], material["params_per_material"]) == ("original", None, 12)
    assert material["loss"] < 1e-3


@pytest.mark.skipif(not jit_available(), reason="Dr.Jit's LLVM backend is not available (neuenh[export]; libLLVM 17+)")
def test_the_jit_kernel_fits_as_the_torch_kernel_does_and_repeats_itself(table, tmp_path):
    """``--kernel jit``: the same protocol (named in the report) on the compiled kernel, ending where the
    torch kernel's fit ends (3 epochs: rounding has not yet moved an end point; test_fit_jit.py), and a
    second run ends exactly where the first did (the kernel's sums have a fixed order). A bundle of small
    modules: the shipped model's kernel builds for ~8-15 s on a new machine (``ggx_states.small_ggx``)."""
    from neuenh.checkpoint import Bundle
    from ggx_states import small_ggx

    Bundle(small_ggx("00010001000", seed=1)).save(tmp_path / "small")
    runs = [neuenh_here("fit", "--model", tmp_path / "small", table, "--capacity", "latent", "--epochs", "3",
                        "--kernel", kernel, "--json") for kernel in ("torch", "jit", "jit")]
    assert [out.returncode for out in runs] == [0, 0, 0], [out.stderr for out in runs]
    reports = [json.loads(out.stdout) for out in runs]
    assert [r["protocol"]["kernel"] for r in reports] == ["torch", "jit", "jit"]
    (torch_fit,), (jit_fit,), (again,) = (r["materials"] for r in reports)
    assert jit_fit["loss"] == pytest.approx(torch_fit["loss"], rel=1e-2)
    assert again["loss"] == jit_fit["loss"]


def test_a_bundle_with_an_encoder_starts_fits_from_it_too_and_keeps_it(table, tmp_path):
    """``neuenh fit --model BUNDLE --capacity latent`` with an encoder (``neuenh encoder train`` writes
    one): its prediction is one of the latent fit's starts, and the bundle the fit writes keeps the
    encoder for the next fit; the shipped model has none (docs/BENCHMARKS.md, "The encoder as a start")."""
    from neuenh.checkpoint import Bundle
    from neuenh.encoder import EncoderConfig, MaterialEncoder
    from neuenh.models import get_model

    model = get_model("ggx", state="00010000000", seed=1)
    encoder = MaterialEncoder(model.specs, model.used_specs().names, model.latent_dim,
                              EncoderConfig(width=8, depth=1, heads=1, head_hidden=8))
    Bundle(model, encoder=encoder).save(tmp_path / "with-encoder")
    out = neuenh_here("fit", "--model", tmp_path / "with-encoder", table, "--capacity", "latent", "--epochs", "6",
                      "--json", "-o", tmp_path / "fitted")
    assert out.returncode == 0, out.stderr
    assert json.loads(out.stdout)["protocol"]["encoder_start"] is True
    assert Bundle.load(tmp_path / "fitted").encoder is not None
    shipped = neuenh_here("fit", "--model", "enhanced-ggx", table, "--capacity", "latent", "--epochs", "6", "--json")
    assert json.loads(shipped.stdout)["protocol"]["encoder_start"] is False


@pytest.mark.parametrize(
    "args,message",
    [
        (["fit", "missing.npz"], "missing.npz: no such file"),
        (["fit", "--model", "phong", "TABLE"], "--model 'phong' is neither an analytical model"),
        (["fit", "BAD"], "f_r has negative values"),
        (["fit", "--jobs", "0", "TABLE"], "--jobs must be at least 1, got 0"),
        (["fit", "--capacity", "everything", "TABLE"], "capacity must be one of auto, analytical, original, latent"),
        # names no file system holds (pathlib's stat raises for them, where it returns False for a missing file)
        (["fit", "LONG"], "not a usable path (File name too long)"),
        (["fit", "--model", "LONG", "TABLE"], "is neither an analytical model"),
        (["fit", "TABLE", "-o", "TMP/LONG"], "File name too long"),
    ],
    ids=["missing-file", "unknown-model", "bad-table", "no-jobs", "unknown-capacity", "long-name", "long-model",
         "long-output"],
)
def test_user_mistakes_exit_2_with_one_line(table, tmp_path, args, message):
    bad = tmp_path / "bad.npz"
    np.savez(bad, wi=[[0, 0, 1.0]], wo=[[0, 0, 1.0]], f_r=[[-1.0, 0, 0]])
    long = "é" * 300  # 600 bytes: over any file system's 255 for one name
    args = [str(table) if a == "TABLE" else str(bad) if a == "BAD" else long if a == "LONG" else
            a.replace("TMP", str(tmp_path)).replace("LONG", long) for a in args]
    out = neuenh_here(*args)
    assert out.returncode == 2
    assert message in out.stderr and "Traceback" not in out.stderr
    assert len(out.stderr.strip().splitlines()) == 1


def test_jobs_fit_the_materials_in_processes_each_as_its_share_alone(tmp_path):
    """``--jobs 2``: three tables fitted in two spawned processes of one thread; the report lists
    them in the given order, each record (corrections included) and loss exactly what
    ``fit_materials`` of its share alone gives in this one-thread process
    (``neuenh.fit.parallel.shares``): the processes change where a fit runs, not what it computes."""
    from neuenh.data.samples import Samples
    from neuenh.data.table import read_table
    from neuenh.fit import FitOptions, fit_materials
    from neuenh.fit.parallel import shares
    from neuenh.pretrained import load_model

    tables = [write_table(tmp_path / f"{m.name}.npz", *m.samples(300, seed=i))
              for i, m in enumerate(synthetic_ggx(3, seed=5))]
    out = neuenh_on_a_terminal("fit", "--model", "enhanced-ggx", *tables, "--capacity", "last-layer", "--epochs", "8",
                               "--jobs", "2", "--json")
    assert out.returncode == 0, out.stderr
    terminal = out.stderr
    # the bar on the terminal: none done, then each share as it finishes (shares of 2 and 1), then a newline
    assert "] 0/3 " in terminal and "] 3/3 " in terminal and terminal.endswith("\n"), terminal
    assert ("] 2/3 " in terminal) != ("] 1/3 " in terminal), terminal
    report = json.loads(out.stdout)
    assert torch.get_num_threads() == 1, "the suite runs one torch thread (tests/conftest.py)"
    (model, trained), samples = load_model("enhanced-ggx"), Samples.concat([read_table(t) for t in tables])
    protocol = FitOptions(capacity="last-layer", epochs=8).protocol_for(model)
    expected = []
    for share in shares(3, 2):
        part = samples.select(share)
        expected += fit_materials(model, part, protocol, trained=trained).report(model, part)["materials"]
    assert [m["name"] for m in report["materials"]] == [t.stem for t in tables]
    assert all(m["capacity"] == "last-layer" and m["corrections"] for m in report["materials"])
    assert report["materials"] == expected and report["protocol"]["processes"] == 2


def test_usage_error_from_argparse_exits_2():
    out = neuenh_here("fit")
    assert out.returncode == 2 and "MEASUREMENTS" in out.stderr


# -- held-out evaluation: --test and --predictions ---------------------------------------------
@pytest.fixture(scope="module")
def held_out(tmp_path_factory):
    """Held-out rows of the same material as ``table`` (another seed), under another file name."""
    (material,) = synthetic_ggx(1, seed=8, noise_sigma=0.0)
    wi, wo, f = material.samples(1000, seed=1)
    return write_table(tmp_path_factory.mktemp("h") / "steel_test.npz", wi, wo, f)


@pytest.fixture(scope="module")
def heldout_run(table, held_out, tmp_path_factory):
    """One user run: fit ``table``, measure on ``held_out``, write predictions; (report, dir)."""
    out_dir = tmp_path_factory.mktemp("pred")
    out = neuenh_here("fit", "--model", "ggx", table, "--epochs", "40", "--json", "--test", held_out,
                      "--predictions", out_dir / "pred.npz")
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout), out_dir


def test_test_adds_heldout_log_l1_to_json_and_table(held_out, heldout_run):
    (material,) = heldout_run[0]["materials"]
    assert material["name"] == "steel" and material["heldout_samples"] == 1000
    assert material["heldout_table"] == str(held_out)
    assert 0 < material["heldout_log_l1"] < 0.1 and abs(material["heldout_log_l1"] - material["loss"]) < 0.02
    from neuenh_service.cli.tables import fit_report  # the text report (without --json) of the same run

    assert f"steel: log-L1 {material['loss']:.5f}  held-out {material['heldout_log_l1']:.5f}" in fit_report(heldout_run[0])


def test_predictions_are_the_fitted_model_at_the_heldout_directions(held_out, heldout_run):
    from neuenh.data.table import read_table
    from neuenh.models import get_model

    report, out_dir = heldout_run
    pred = out_dir / "pred.npz"
    assert report["predictions"] == str(pred)
    assert sorted(p.name for p in out_dir.iterdir()) == ["pred.npz"]  # atomic: no temporary left
    held = read_table(held_out)
    with np.load(pred, allow_pickle=False) as npz:
        assert npz["material_names"].tolist() == ["steel"] and (npz["material"] == 0).all()
        np.testing.assert_array_equal(npz["wi"], held.wi.numpy())
        np.testing.assert_array_equal(npz["wo"], held.wo.numpy())
        f_r = npz["f_r"]
    # independently: the model evaluated with the parameters the JSON reports (rounded to 6 digits)
    params = {k: torch.tensor(v, dtype=torch.float64) for k, v in report["materials"][0]["params"].items()}
    expected = get_model("ggx").evaluate(held.wi.double(), held.wo.double(), params).numpy()
    np.testing.assert_allclose(f_r, expected, rtol=2e-3, atol=1e-6)
    cos = np.clip(held.wi[:, 2].double().numpy(), 0, None)[:, None]
    mine = np.mean(np.abs(np.log1p(held.f_r.double().numpy() * cos) - np.log1p(f_r.astype(np.float64) * cos)))
    assert mine == pytest.approx(report["materials"][0]["heldout_log_l1"], rel=1e-4, abs=1e-7)
    assert torch.equal(read_table(pred).f_r, torch.from_numpy(f_r))  # one material: readable as a table


@pytest.mark.parametrize(
    "args,message",
    [
        (["--predictions", "OUT"], "--predictions needs --test"),
        (["--test", "HELD", "HELD"], "--test takes one held-out table per fitted table, in the same order: got 2 for 1"),
        (["--test", "TABLE"], "is also a fitted table"),
        (["--test", "missing.npz"], "missing.npz: no such file"),
        (["--test", "HELD", "--predictions", "NODIR"], "does not exist"),
    ],
    ids=["predictions-without-test", "count-mismatch", "test-is-fitted", "missing-test", "no-output-dir"],
)
def test_heldout_mistakes_exit_2_with_one_line(table, held_out, tmp_path, capsys, args, message):
    """In-process through ``cli.main.main`` (the exit code and message the subprocess would give;
    these checks run before any fitting)."""
    from neuenh_service.cli.main import main

    subs = {"OUT": tmp_path / "p.npz", "HELD": held_out, "TABLE": table, "NODIR": tmp_path / "no" / "p.npz"}
    code = main(["fit", "--model", "ggx", str(table), "--epochs", "1", *[str(subs.get(a, a)) for a in args]])
    err = capsys.readouterr().err
    assert code == 2
    assert message in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1
    assert list(tmp_path.iterdir()) == []  # nothing written


def test_the_capacities_by_name_are_the_ones_the_fit_frees():
    """``neuenh fit --help`` and scene files name the capacities without importing torch
    (``neuenh.capacities``); the fit's table of what each one frees has exactly those names."""
    from neuenh.capacities import CAPACITY_NAMES
    from neuenh.fit.capacity import CAPACITIES

    assert tuple(CAPACITIES) == CAPACITY_NAMES


# -- measured files (RGL, MERL): drawn, fitted, measured on an independent draw -----------------
@pytest.fixture(scope="module")
def merl_ggx(tmp_path_factory):
    """A MERL ``.binary`` of an isotropic GGX material (alpha 0.3, no noise) and the material."""
    from neuenh.data.merl import write_merl

    (material,) = synthetic_ggx(1, seed=8, noise_sigma=0.0)
    path = write_merl(tmp_path_factory.mktemp("merl") / "gold.binary",
                      lambda wi, wo: material.evaluate(wi, wo).numpy())
    return path, material


@pytest.fixture(scope="module")
def drawn_run(merl_ggx, tmp_path_factory):
    """``neuenh fit --model ggx gold.binary --samples 1500 --test-samples 400 --predictions``."""
    out_dir = tmp_path_factory.mktemp("drawn")
    out = neuenh_here("fit", "--model", "ggx", merl_ggx[0], "--samples", "1500", "--test-samples", "400",
                      "--epochs", "40", "--json", "--predictions", out_dir / "pred.npz", "-o", out_dir / "bundle")
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout), out_dir


def test_a_measured_file_is_drawn_fitted_and_measured_on_an_independent_draw(merl_ggx, drawn_run):
    """The fit draws ``--samples`` pairs of the MERL file, half near the mirror; the held-out pairs are
    the independent draw of ``draw_fit_test`` (the README's protocol) and the model fits its own
    material to within the table's binning."""
    from neuenh.data.directions import near_mirror_mask
    from neuenh.data.measured import load_measured
    from neuenh.study.heldout import draw_fit_test

    report, out_dir = drawn_run
    (material,) = report["materials"]
    assert material["name"] == "gold" and material["heldout_samples"] == 400
    assert material["heldout_table"] == str(merl_ggx[0])
    assert material["heldout_log_l1"] < 0.05  # GGX on its own material, read through MERL's bins
    _, test, split = draw_fit_test(load_measured(merl_ggx[0]), 1500, 400, 0, 0.5)
    assert split == "independent draws"
    with np.load(out_dir / "pred.npz", allow_pickle=False) as npz:
        np.testing.assert_array_equal(npz["wi"], test.wi.numpy())
        np.testing.assert_array_equal(npz["wo"], test.wo.numpy())
    assert near_mirror_mask(test.wi.double(), test.wo.double()).double().mean() >= 0.5  # half drawn there, and chance
    assert Bundle.load(out_dir / "bundle").provenance["drawn"] == {"samples": 1500, "near_mirror": 0.5, "seed": 0,
                                                                    "test_samples": 400}


def test_tables_and_measured_files_fit_together_each_as_it_is(merl_ggx, table):
    """A table keeps its rows, a measured file is drawn (docs/EXPORT.md fits a .bsdf beside a .npz)."""
    out = neuenh_here("fit", "--model", "ggx", table, merl_ggx[0], "--samples", "700", "--epochs", "20", "--json")
    assert out.returncode == 0, out.stderr
    steel, gold = json.loads(out.stdout)["materials"]
    assert (steel["name"], gold["name"]) == ("steel", "gold")
    assert (steel["samples"], gold["samples"]) == (3000, 700)


@pytest.mark.parametrize(
    "args,message",
    [
        (["MERL", "--test", "TABLE"], "measured files (RGL, MERL) are measured held out with --test-samples N"),
        (["TABLE", "MERL", "--test-samples", "10"], "--test-samples draws from measured files"),
        (["MERL", "--near-mirror", "1.5"], "--near-mirror is a share of the pairs, in [0, 1]; got 1.5"),
        (["MERL", "--samples", "0"], "--samples must be at least 1, got 0"),
        (["MERL", "--test-samples", "0"], "--test-samples must be at least 1, got 0"),
        (["NBRDF"], "NBRDF network weights (a model, not measurements); a fit reads measurement tables"),
        (["MERL", "--predictions", "OUT"], "--predictions needs --test or --test-samples"),
    ],
    ids=["test-tables", "test-samples-of-tables", "near-mirror", "no-samples", "no-test-samples", "nbrdf",
         "predictions"],
)
def test_measured_file_mistakes_exit_2_with_one_line(merl_ggx, table, tmp_path, args, message):
    """Refused before anything is drawn or fitted (in-process: the exit code and line the command gives)."""
    from data_files import nbrdf_weights

    np.savez(tmp_path / "weights.npz", **nbrdf_weights(["only"], seed=2))
    subs = {"MERL": merl_ggx[0], "TABLE": table, "NBRDF": tmp_path / "weights.npz", "OUT": tmp_path / "p.npz"}
    out = neuenh_here("fit", "--model", "ggx", *[str(subs.get(a, a)) for a in args])
    assert out.returncode == 2
    assert message in out.stderr and "Traceback" not in out.stderr
    assert len(out.stderr.strip().splitlines()) == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["weights.npz"]  # nothing written
