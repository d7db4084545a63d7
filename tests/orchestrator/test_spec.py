import pytest

from orchestrator.spec import SpecError, load_spec, parse_spec

BASE = {"data": [{"source": "synthetic_zoo", "materials": 2, "samples": 10}]}


def test_the_quickstart_spec_is_valid():
    spec = load_spec("examples/quickstart.yaml")
    assert spec.model == "ggx" and spec.search.radius == 1 and spec.digits() == 2


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
        ({"data": [{"source": "merl_raw"}]}, "does not match any of the expected tags"),
        ({"data": [{"source": "synthetic_zoo", "families": ["velvet"]}]}, "unknown zoo families"),
    ],
    ids=["no-data", "model", "typo", "radius", "position", "digit", "lr", "source", "family"],
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
