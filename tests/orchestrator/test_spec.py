import pytest

from neuenh_service.orchestrator.spec import FitScoreSpec, SpecError, load_spec, parse_spec

BASE = {"data": [{"source": "synthetic_zoo", "materials": 2, "samples": 10}]}


def test_the_quickstart_spec_is_valid():
    spec = load_spec("examples/quickstart.yaml")
    assert spec.model == "ggx" and spec.search.radius == 1 and spec.digits() == 2


def test_the_reference_spec_decays_its_lr_and_polishes():
    spec = load_spec("examples/reference.yaml")
    assert spec.train_config().lr_final == spec.train.lr_final == 5e-4
    polish = spec.polish_config()
    assert (polish.epochs, polish.lr, polish.lr_final) == (40, 5e-3, 5e-4)
    assert spec.train_config().precision == polish.precision == "float32"


def test_a_bfloat16_spec_trains_every_stage_at_that_precision():
    spec = parse_spec({**BASE, "train": {"precision": "bfloat16", "compile": True}, "search": {"polish_epochs": 5}})
    assert {(c.precision, c.compile) for c in (spec.train_config(), spec.train_config(7), spec.polish_config())} \
        == {("bfloat16", True)}


def test_a_latent_prior_reaches_every_stage_of_training():
    spec = parse_spec({**BASE, "train": {"latent_prior": 1e-3}, "search": {"polish_epochs": 5}})
    assert {c.latent_prior for c in (spec.train_config(), spec.train_config(7), spec.polish_config())} == {1e-3}
    assert parse_spec(BASE).train_config().latent_prior == 0.0


@pytest.mark.parametrize(
    "change,message",
    [
        ({"data": []}, "data: List should have at least 1 item"),
        ({"model": "phong"}, "unknown model 'phong'"),
        ({"serch": {}}, "serch: Extra inputs are not permitted"),
        ({"search": {"radius": -1}}, "search.radius"),
        ({"search": {"fixed": {"Q": 1}}}, "unknown position 'Q'"),
        ({"search": {"fixed": {"D": 2}}}, "digit 2 for D is not in 0..1"),
        ({"train": {"lr": 0}}, "train.lr"),
        ({"train": {"precision": "float16"}}, "train.precision: Input should be 'float32' or 'bfloat16'"),
        ({"train": {"latent_prior": -1e-3}}, "train.latent_prior: Input should be greater than or equal to 0"),
        ({"data": [{"source": "merl_raw"}]}, "does not match any of the expected tags"),
        ({"data": [{"source": "synthetic_zoo", "families": ["velvet"]}]}, "unknown zoo families"),
        ({"train": {"lr": 1e-3, "lr_final": 1e-2}}, r"train: .*lr_final \(0.01\) must not exceed lr \(0.001\)"),
        ({"search": {"polish_epochs": -1}}, "search.polish_epochs"),
        ({"model": "ward", "alternatives": True}, "alternatives: model 'ward' offers none"),
        ({"alternatives": True, "search": {"fixed": {"S": 2}}}, "digit 2 for S is not in 0..1"),
        ({"alternatives": True, "search": {"allowed": {"D": [0, 6]}}}, r"digits \[0, 6\] for D are not all in 0..5"),
        ({"data": [{"source": "table", "paths": ["x.npz"], "near_mirror": 0.5}]}, "near_mirror"),
        ({"search": {"score": "fit"}}, r"data\[0\] \(synthetic_zoo\) holds none out"),
        ({"search": {"score": "fit"}, "data": [{"source": "synthetic_zoo", "materials": 6, "holdout": 2},
                                               {"source": "synthetic_ggx", "materials": 4}]},
         r"every data source, but data\[1\] \(synthetic_ggx\) holds none out"),
        ({"search": {"fit_score": {"capacity": "rank-8"}}},
         "search.fit_score.capacity: Input should be 'latent' or 'auto'"),
    ],
    ids=["no-data", "model", "typo", "radius", "position", "digit", "lr", "precision", "latent-prior", "source", "family", "lr-final", "polish",
         "alternatives-model", "alternatives-digit", "alternatives-allowed", "table-near-mirror",
         "fit-score-without-holdout", "fit-score-blind-to-a-source", "fit-score-capacity"],
)
def test_bad_specs_name_the_field(change, message):
    with pytest.raises(SpecError, match=message):
        parse_spec({**BASE, **change})


def test_spec_files_report_their_path(tmp_path):
    bad = tmp_path / "job.yaml"
    bad.write_text("model: [unclosed")
    with pytest.raises(SpecError, match="job.yaml: not valid YAML"):
        load_spec(bad)
    with pytest.raises(SpecError, match="nope.yaml: no such file"):
        load_spec(tmp_path / "nope.yaml")
    (tmp_path / "folder.yaml").mkdir()
    with pytest.raises(SpecError, match="folder.yaml: a folder, not a job spec"):
        load_spec(tmp_path / "folder.yaml")
    bad.write_bytes(b"\x94 binary")
    with pytest.raises(SpecError, match="job.yaml: not valid YAML"):
        load_spec(bad)


def test_the_fit_scored_reference_spec_holds_out_every_kind_and_fits_as_users_do():
    """examples/reference-fit.yaml: every source holds materials out (the zoo one of each family) and
    the score fits them for the epochs ``neuenh fit`` runs (docs/BENCHMARKS.md, issue 23)."""
    from neuenh.data.sources import held_out
    from neuenh.data.synthetic import ZOO_FAMILIES
    from neuenh.fit import LatentAdam

    spec = load_spec("examples/reference-fit.yaml")
    assert spec.search.score == "fit" and all(source.holdout for source in spec.data)
    zoo = next(source for source in spec.data if source.source == "synthetic_zoo")
    kinds = zoo.strata(zoo.materials)  # the family of each zoo material
    assert {kinds[i] for i in held_out(zoo, zoo.materials)} == set(range(len(ZOO_FAMILIES)))
    assert spec.search.fit_score.epochs == LatentAdam().epochs


def test_the_default_fit_score_fits_as_users_do():
    """A spec that holds materials out without naming a budget scores them with the users' fit's
    epochs, in the spec and in the worker's config alike (stop 60: 100-epoch fits ranked a search's
    rounds otherwise than users' fits did)."""
    from neuenh.fit import LatentAdam
    from neuenh.train import FitScoreConfig

    spec = parse_spec({"data": [{"source": "synthetic_zoo", "materials": 4, "samples": 10, "holdout": 2}]})
    assert spec.train_config().fit_score == FitScoreConfig(seed=spec.train.seed)
    assert spec.search.fit_score.epochs == FitScoreConfig().epochs == LatentAdam().epochs


def test_a_fit_score_at_the_users_capacity_reaches_the_worker():
    """``search.fit_score.capacity`` (the spec imports no torch, so it lists the choices itself): the
    same choices as the worker's config, and the one asked for is the one the worker fits at."""
    import typing

    from neuenh.train import SCORE_CAPACITIES, FitScoreConfig

    assert typing.get_args(FitScoreSpec.model_fields["capacity"].annotation) == SCORE_CAPACITIES
    data = [{"source": "synthetic_zoo", "materials": 4, "samples": 10, "holdout": 2}]
    spec = parse_spec({"search": {"fit_score": {"capacity": "auto"}}, "data": data})
    assert spec.train_config().fit_score == FitScoreConfig(seed=spec.train.seed, capacity="auto")
    assert parse_spec({"data": data}).train_config().fit_score.capacity == "latent"


def test_the_curriculum_spec_grows_the_shipped_state_on_the_reference_data():
    """examples/reference-curriculum.yaml (stop 54): from the shipped model's analytical choices it can
    reach only the shipped state and its two halves, on examples/reference.yaml's data and schedule."""
    import itertools

    from neuenh.pretrained import load_model
    from neuenh.search import initial_state

    spec, reference = load_spec("examples/reference-curriculum.yaml"), load_spec("examples/reference.yaml")
    constraints, m, n = spec.constraints(), spec.digits(), len(spec.positions())
    states = {"".join(map(str, s)) for s in itertools.product(*(constraints.digits_at(i, m) for i in range(n)))}
    assert load_model("enhanced-ggx")[0].state == "40730003000"
    assert states == {"40700000000", "40730000000", "40700003000", "40730003000"}
    assert "".join(map(str, initial_state(n, m, constraints))) == "40700000000"
    assert spec.data == reference.data and spec.module == reference.module and spec.train == reference.train
    assert (spec.search.epochs_per_round, spec.search.warmup_epochs, spec.search.polish_epochs) == (
        reference.search.epochs_per_round, reference.search.warmup_epochs, reference.search.polish_epochs)


def test_the_paper_scale_spec_is_valid_and_has_the_papers_sizes():
    """examples/paper.yaml (issue 18) is for clusters with GPUs: validated here, not run."""
    from neuenh.train import TrainConfig

    spec = load_spec("examples/paper.yaml")
    assert (spec.search.epochs_per_round, spec.train.batch_size, spec.train.lr) == (30, 100_000, 1e-3)
    assert spec.resources.gpus_per_candidate == 1 and spec.module.hidden == [16, 32, 16] and spec.latent_dim == 27
    nbrdf, ggx = spec.data
    assert 100 * nbrdf.samples + ggx.materials * ggx.samples == 28_000_000  # the MERL 100 plus the synthetic 100
    assert isinstance(spec.train_config(), TrainConfig)


def test_alternatives_give_each_position_its_own_digits_and_names():
    spec = parse_spec({**BASE, "alternatives": True, "search": {"max_neural": 2}})
    assert spec.digits() == 6  # D: ggx, its module, beckmann, gtr, student_t, hazy_ggx
    constraints = spec.constraints()
    assert constraints.digits_at(spec.positions().index("S"), 6) == (0, 1)
    assert constraints.neural == frozenset({1}) and constraints.max_neural == 2
    assert spec.choice_names()[("F", 2)] == "conductor"
    assert parse_spec(BASE).choice_names() == {}  # binary states keep '+G'


@pytest.mark.parametrize("alternatives, hidden", [(False, None), (True, None), (True, [[8], [16, 16]])])
def test_a_spec_reads_its_models_positions_and_choices_from_the_graph_as_the_model_has_them(alternatives, hidden):
    """The spec is checked against its model's graph, without building the torch model: the same
    positions and the same number of choices at each as the model the search trains."""
    module = {"hidden": hidden[0], "alternatives": hidden[1:]} if hidden else {}
    spec = parse_spec({**BASE, "alternatives": alternatives, "module": module})
    model = spec.model_instance()
    assert spec.positions() == model.positions and spec.digit_counts() == model.digit_counts


def test_the_precisions_a_spec_offers_are_those_training_runs_at():
    from typing import get_args

    from neuenh.train import PRECISIONS
    from neuenh_service.orchestrator.spec import Precision

    assert get_args(Precision) == tuple(PRECISIONS)
