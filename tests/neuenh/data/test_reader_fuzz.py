"""Fuzzing the binary readers: truncated and bit-flipped files either load (and then evaluate
without error) or raise ``DataError`` — never another exception.

Examples are derandomised (the suite is reproducible) and kept few, so the run stays short.
"""

import math
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from neuenh.data import load_measured
from neuenh.data.errors import DataError
from neuenh.data.merl import FILE_SIZE, load_merl, write_merl
from neuenh.data.rgl import load_rgl

from data_files import hemisphere, tensor_file_bytes, tiny_rgl_fields

FUZZ = settings(deadline=None, derandomize=True, database=None, suppress_health_check=[HealthCheck.too_slow])

TENSOR_FILE = tensor_file_bytes(tiny_rgl_fields())
TENSOR_HEADER = TENSOR_FILE.index(b"valid") + 40  # the last field entry ends before this


def mutations(length: int, hot: int):
    """For a file of ``length`` bytes: a truncation, some byte flips (XOR with 1..255), or both;
    positions favour the first ``hot`` bytes (the header)."""
    position = st.one_of(st.integers(0, hot - 1), st.integers(0, length - 1))
    flips = st.lists(st.tuples(position, st.integers(1, 255)), min_size=1, max_size=4)
    cut = st.one_of(position, st.integers(length - 64, length - 1))
    return st.one_of(
        st.builds(lambda n: ("truncate", n, []), cut),
        st.builds(lambda f: ("flip", None, f), flips),
        st.builds(lambda n, f: ("both", n, f), cut, flips),
    )


def mutate(content: bytes, mutation) -> bytes:
    _, cut, flips = mutation
    data = bytearray(content)
    for at, mask in flips:
        data[at] ^= mask
    return bytes(data if cut is None else data[:cut])


def exercise(material) -> None:
    """A material that loaded must evaluate and sample without error."""
    wi, wo = hemisphere(64, 0), hemisphere(64, 1)
    f = material.evaluate(torch.from_numpy(wi), torch.from_numpy(wo))
    assert f.shape == (64, 3) and torch.isfinite(f).all()
    swi, swo, sf = material.samples(16, seed=0)
    assert sf.shape == (16, 3) and torch.isfinite(sf).all()


def load_all_ways(path: Path, loader) -> bool:
    """Load with the format's reader and with ``load_measured``; both succeed or raise DataError."""
    outcomes = []
    for load in (loader, load_measured):
        try:
            material = load(path)
        except DataError as exc:
            assert str(path) in str(exc)
            outcomes.append(False)
        else:
            exercise(material)
            outcomes.append(True)
    return outcomes[0]


@pytest.fixture(scope="module")
def scratch(tmp_path_factory):
    return tmp_path_factory.mktemp("fuzz")


def test_the_unmutated_files_load(scratch, merl_content):
    path = scratch / "ok.bsdf"
    path.write_bytes(TENSOR_FILE)
    assert load_all_ways(path, load_rgl)
    path = scratch / "ok.binary"
    path.write_bytes(merl_content)
    assert load_all_ways(path, load_merl)


@settings(FUZZ, max_examples=200)
@given(mutation=mutations(len(TENSOR_FILE), TENSOR_HEADER))
def test_tensor_file_mutations_raise_only_data_error(scratch, mutation):
    path = scratch / "fuzzed.bsdf"
    path.write_bytes(mutate(TENSOR_FILE, mutation))
    load_all_ways(path, load_rgl)


@pytest.fixture(scope="module")
def merl_content(tmp_path_factory):
    """A MERL file with some invalid bins, so flips can also touch the negative markers."""
    table = np.full((3, 90, 90, 180), 1 / math.pi) * np.array([0.3, 0.5, 0.7])[:, None, None, None]
    table[:, :, 80:, :] = -1.0
    path = write_merl(tmp_path_factory.mktemp("merl") / "base.binary", table)
    content = path.read_bytes()
    assert len(content) == FILE_SIZE
    return content


@settings(FUZZ, max_examples=40)
@given(mutation=mutations(FILE_SIZE, 64))
def test_merl_mutations_raise_only_data_error(scratch, merl_content, mutation):
    path = scratch / "fuzzed.binary"
    path.write_bytes(mutate(merl_content, mutation))
    load_all_ways(path, load_merl)
