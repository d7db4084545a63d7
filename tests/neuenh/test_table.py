import numpy as np
import pytest
import torch

from neuenh.data.table import TableError, check_table, read_table, write_table


def _good(n=50):
    g = np.random.default_rng(0)
    w = g.normal(size=(2, n, 3))
    w[..., 2] = np.abs(w[..., 2])
    w /= np.linalg.norm(w, axis=2, keepdims=True)
    return {"wi": w[0], "wo": w[1], "f_r": g.uniform(0, 2, (n, 3))}


def test_round_trip(tmp_path):
    arrays = _good()
    path = write_table(tmp_path / "mat.npz", **arrays)
    samples = read_table(path)
    assert samples.names == ("mat",) and len(samples) == 50
    assert check_table(path) == 50
    assert torch.allclose(samples.f_r, torch.as_tensor(arrays["f_r"], dtype=torch.float32))


def _with(**changes):
    arrays = _good()
    for key, value in changes.items():
        if value is None:
            arrays.pop(key)
        else:
            arrays[key] = value(arrays[key]) if callable(value) else value
    return arrays


def _nan(a):
    a = a.copy()
    a[3, 1] = np.nan
    return a


@pytest.mark.parametrize(
    "arrays,match",
    [
        (_with(f_r=None), r"missing array\(s\) \['f_r'\]"),
        (_with(wi=lambda a: a[:, :2]), "wi must be a numeric"),
        (_with(f_r=lambda a: a.astype(np.complex64)), "f_r must be a numeric"),
        (_with(wo=lambda a: a[:10]), "same length"),
        (_with(f_r=_nan), "f_r has non-finite values .first at row 3"),
        (_with(f_r=lambda a: -a), "negative"),
        (_with(wi=lambda a: 2 * a), "wi must hold unit vectors"),
        (_with(wi=lambda a: a[:0], wo=lambda a: a[:0], f_r=lambda a: a[:0]), "empty"),
    ],
    ids=["missing", "shape", "complex", "length", "nan", "negative", "non-unit", "empty"],
)
@pytest.mark.parametrize("reader", [read_table, check_table], ids=["read", "check"])
def test_bad_tables_name_the_file_and_the_problem(tmp_path, arrays, match, reader):
    path = tmp_path / "bad.npz"
    np.savez(path, **arrays)
    with pytest.raises(TableError, match=match) as info:
        reader(path)
    assert "bad.npz" in str(info.value)


def test_not_an_npz(tmp_path):
    path = tmp_path / "junk.npz"
    path.write_bytes(b"PK\x03\x04 not really a zip")
    with pytest.raises(TableError, match="junk.npz: not a readable .npz"):
        read_table(path)


def test_a_member_that_is_not_an_array(tmp_path):
    import zipfile

    path = tmp_path / "raw.npz"
    arrays = _good()
    np.savez(path, wi=arrays["wi"], wo=arrays["wo"])
    with zipfile.ZipFile(path, "a") as z:
        z.writestr("f_r", b"not a npy file")  # np.load returns raw bytes for non-.npy members
    with pytest.raises(TableError, match="raw.npz: f_r is not an array"):
        read_table(path)
