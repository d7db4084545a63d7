"""``neuenh.export.export``: the one entry point of every format."""

import sys

import pytest
import torch

from neuenh.export import FORMATS, MissingRuntime, export
from neuenh.models import get_model


def test_a_format_whose_runtime_is_missing_says_what_to_install(monkeypatch, tmp_path):
    model = get_model("ggx")
    one = {s.name: torch.full((s.width,), s.init) for s in model.specs}
    monkeypatch.setitem(sys.modules, "onnx", None)  # as if the neuenh[export] extra were not installed
    monkeypatch.delitem(sys.modules, "neuenh.export.onnx", raising=False)
    with pytest.raises(MissingRuntime, match=r"the onnx export needs onnx.*pip install 'neuenh\[export\]'"):
        export(model, {"m": one}, "onnx", tmp_path)
    with pytest.raises(ValueError, match="unknown export format 'usd'; choose one of glsl, onnx, mitsuba"):
        export(model, {"m": one}, "usd", tmp_path)
    with pytest.raises(ValueError, match="nothing to export"):
        export(model, {}, "glsl", tmp_path)
    assert FORMATS == ("glsl", "onnx", "mitsuba")
