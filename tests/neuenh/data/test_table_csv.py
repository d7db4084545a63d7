"""Measurement tables as CSV (and weights in both formats): round trips, detection by content,
and every problem reported with the file, the row and what is wrong."""

from pathlib import Path

import numpy as np
import pytest
import torch

from neuenh.data import load_measured
from neuenh.data.errors import DataError
from neuenh.data.measured import TableMaterial, detect_format
from neuenh.data.table import CSV_COLUMNS, TableError, check_table, load_table, read_table, write_table

from data_files import hemisphere

HEADER = ",".join(CSV_COLUMNS)


def _arrays(n=40, seed=0):
    rng = np.random.default_rng(seed)
    return hemisphere(n, seed), hemisphere(n, seed + 1), rng.uniform(0, 3, (n, 3)), rng.uniform(0.5, 2, n)


def _csv(path: Path, rows: list[str], header: str = HEADER) -> Path:
    path.write_text("\n".join([header, *rows]) + "\n")
    return path


GOOD_ROW = "0,0,1,0.6,0,0.8,0.1,0.2,0.3"


@pytest.mark.parametrize("suffix", [".csv", ".npz"])
@pytest.mark.parametrize("weighted", [False, True], ids=["plain", "weighted"])
def test_round_trip_is_exact_in_float32(tmp_path, suffix, weighted):
    wi, wo, f, w = _arrays()
    path = write_table(tmp_path / f"felt{suffix}", wi, wo, f, weight=w if weighted else None)
    table = load_table(path)
    assert table.format == suffix[1:] and table.samples.names == ("felt",) and len(table.samples) == 40
    for got, want in ((table.samples.wi, wi), (table.samples.wo, wo), (table.samples.f_r, f)):
        assert torch.equal(got, torch.as_tensor(want.astype(np.float32)))
    if weighted:
        assert torch.equal(table.weight, torch.as_tensor(w.astype(np.float32)))
    else:
        assert table.weight is None


def test_csv_columns_in_any_order_any_case_with_comments_and_a_bom(tmp_path):
    path = tmp_path / "t.csv"
    path.write_text("\ufeff# measured 2024-05-02\n\n  # another comment\nR,G,B,Wo_X,wo_y,wo_z,wi_x,wi_y,wi_z\n"
                    "0.1,0.2,0.3,0.6,0,0.8,0,0,1\n\n# a comment between rows\n1,2,3,0,0,1,0,0.6,0.8\n")
    samples = read_table(path)
    torch.testing.assert_close(samples.f_r, torch.tensor([[0.1, 0.2, 0.3], [1, 2, 3]]))
    torch.testing.assert_close(samples.wo, torch.tensor([[0.6, 0, 0.8], [0, 0, 1]]))
    torch.testing.assert_close(samples.wi, torch.tensor([[0, 0, 1.0], [0, 0.6, 0.8]]))


def test_csv_is_recognised_by_content_and_keeps_its_weights(tmp_path):
    wi, wo, f, w = _arrays(30)
    write_table(tmp_path / "x.csv", wi, wo, f, weight=w)
    disguised = tmp_path / "measurement.bsdf"
    (tmp_path / "x.csv").rename(disguised)
    assert detect_format(disguised) == "table"
    material = load_measured(disguised, name="velvet")
    assert isinstance(material, TableMaterial) and material.name == "velvet" and len(material) == 30
    assert material.metadata["format"] == "csv" and material.metadata["weight"]["used_in_training"] is False
    assert torch.equal(material.weight, torch.as_tensor(w.astype(np.float32)))
    assert material.metadata["weight"]["max"] == pytest.approx(float(w.max()), rel=1e-6)


def test_csv_header_with_a_typo_gets_a_precise_error_not_unrecognised(tmp_path):
    path = _csv(tmp_path / "typo.txt", [GOOD_ROW], header=HEADER.replace("wo_z", "wo_zz"))
    with pytest.raises(DataError, match=r"typo.txt: line 1: header lacks column\(s\) \['wo_z'\]"):
        load_measured(path)


@pytest.mark.parametrize("rows, header, match", [
    ([GOOD_ROW], HEADER.replace(",b", ""), r"line 1: header lacks column\(s\) \['b'\]"),
    ([GOOD_ROW + ",1"], HEADER + ",wieght", r"line 1: unknown column\(s\) \['wieght'\]"),
    ([GOOD_ROW + ",1"], HEADER + ",r", r"line 1: header repeats column\(s\) \['r'\]"),
    ([GOOD_ROW, "0,0,1,0.6,0,0.8,0.1,0.2"], HEADER, r"row 1 \(line 3\): 8 values, the header has 9"),
    ([GOOD_ROW, GOOD_ROW, "0,0,1,0.6,0,0.8,0.1,abc,0.3"], HEADER, r"row 2 \(line 4\): g is not a number \('abc'\)"),
    ([GOOD_ROW, "0,0,1,0.6,0,0.8,0.1,nan,0.3"], HEADER, r"f_r has non-finite values \(first at row 1 \(line 3\)\)"),
    ([GOOD_ROW, "0,0,1,0.6,0,0.8,0.1,-0.2,0.3"], HEADER, r"f_r has negative values \(first at row 1 \(line 3\)\)"),
    ([GOOD_ROW, GOOD_ROW, "0,0,1,0.6,0,0.8,0.1,1e39,0.3"], HEADER,
     r"f_r has values beyond float32's range .*first at row 2 \(line 4\)"),
    ([GOOD_ROW, "0,0,2,0.6,0,0.8,0.1,0.2,0.3"], HEADER, r"wi must hold unit vectors \(row 1 \(line 3\) has norm 2\)"),
    ([GOOD_ROW + ",1", GOOD_ROW + ",-1"], HEADER + ",weight", r"weight has negative values \(first at row 1"),
    ([GOOD_ROW + ",0", GOOD_ROW + ",0"], HEADER + ",weight", "weight is zero on every row"),
    (["# only a comment"], HEADER, "the table is empty"),
    ([], "# nothing but comments", "the table is empty"),
], ids=["missing-column", "unknown-column", "duplicate-column", "short-row", "not-a-number", "nan", "negative", "beyond-float32",
        "non-unit", "negative-weight", "zero-weights", "header-only", "no-header"])
@pytest.mark.parametrize("reader", [read_table, check_table], ids=["read", "check"])
def test_bad_csv_names_file_row_and_problem(tmp_path, rows, header, match, reader):
    path = _csv(tmp_path / "bad.csv", rows, header)
    with pytest.raises(TableError, match=match) as info:
        reader(path)
    assert str(info.value).startswith(str(path))


def test_csv_that_is_not_utf8(tmp_path):
    path = tmp_path / "latin.csv"
    path.write_bytes((HEADER + "\n").encode() + "0,0,1,0.6,0,0.8,0.1,0.2,0.3 # caf\xe9\n".encode("latin-1"))
    with pytest.raises(TableError, match="latin.csv: not a CSV table .not UTF-8 text"):
        read_table(path)


@pytest.mark.parametrize("weight, match", [
    (np.ones((40, 2)), r"weight must be a numeric \(n,\) array"),
    (np.ones(39), "must have the same length, got 40, 40, 40, 39"),
    (np.full(40, np.inf), r"weight has non-finite values \(first at row 0\)"),
])
def test_bad_npz_weights(tmp_path, weight, match):
    wi, wo, f, _ = _arrays()
    np.savez(tmp_path / "w.npz", wi=wi, wo=wo, f_r=f, weight=weight)
    with pytest.raises(TableError, match=match):
        read_table(tmp_path / "w.npz")


def test_missing_table_and_folder(tmp_path):
    with pytest.raises(TableError, match="no such file"):
        read_table(tmp_path / "none.csv")
    with pytest.raises(TableError, match="not a regular file"):
        read_table(tmp_path)


# -- hostile tables (issue 17): refused from their headers, before anything is inflated ---------
def _bomb(path: Path, rows: int) -> Path:
    """Deflated zeros: a few hundred KB on disk, 3 x rows x 3 float64 once read."""
    zeros = np.zeros((rows, 3))
    np.savez_compressed(path, wi=zeros, wo=zeros, f_r=zeros)
    return path


def test_a_decompression_bomb_is_refused_from_its_headers(tmp_path):
    import tracemalloc

    path = _bomb(tmp_path / "bomb.npz", 3_000_000)  # 216 MB of arrays
    assert path.stat().st_size < 2_000_000
    tracemalloc.start()
    try:
        with pytest.raises(TableError, match="3000000 rows exceed the limit of 1000"):
            read_table(path, max_rows=1000)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 5_000_000  # nothing was inflated


def test_a_csv_over_the_row_limit_is_refused(tmp_path):
    wi, wo, f_r, _ = _arrays(n=40)
    path = write_table(tmp_path / "t.csv", wi, wo, f_r)
    assert len(read_table(path, max_rows=40)) == 40
    with pytest.raises(TableError, match="more than 39 rows exceed the limit of 39"):
        read_table(path, max_rows=39)


def test_a_csv_is_counted_while_streaming_and_refused_early(tmp_path):
    """Issue 26, case 5: a 60 MB CSV of ``1,`` lines took a server from 889 MB to 4,474 MB before its
    422 (the whole text split into line objects first). Streamed, it is refused at the first row
    beyond the limit: the reader's peak allocation (tracemalloc) is the lines it holds before parsing
    them — at most the limit's 1000 here, ~130 B each as Python strings — never the file's 60 MB."""
    import tracemalloc

    path = tmp_path / "lines.csv"
    with open(path, "w") as f:
        f.write(HEADER + "\n")
        for _ in range(60):
            f.write("1,\n" * 333_333)  # 60 x 1 MB
    size = path.stat().st_size
    assert size > 59_000_000
    tracemalloc.start()
    try:
        with pytest.raises(TableError, match="more than 1000 rows exceed the limit of 1000"):
            read_table(path, max_rows=1000)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 1000 * 200, f"{peak} bytes allocated reading a {size}-byte file"


def test_an_npz_header_claiming_more_than_the_archive_holds_is_one_error(tmp_path):
    """A header that claims 10^12 rows (numpy would try to allocate 24 TB) names the array."""
    import io
    import zipfile

    def member(shape) -> bytes:
        buffer = io.BytesIO()
        np.lib.format.write_array_header_1_0(buffer, {"descr": "<f8", "fortran_order": False, "shape": shape})
        return buffer.getvalue() + np.zeros(6).tobytes()

    path = tmp_path / "liar.npz"
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr("wi.npy", member((10**12, 3)))
        archive.writestr("wo.npy", member((2, 3)))
        archive.writestr("f_r.npy", member((2, 3)))
    with pytest.raises(TableError, match=r"wi's header claims shape \(1000000000000, 3\)"):
        read_table(path)


@pytest.mark.parametrize("suffix", [".npz", ".csv"])
def test_directions_below_the_horizon_are_refused_naming_the_rows(tmp_path, suffix):
    """Such rows have f_r 0 by definition, and a table of them fitted to log-L1 0.00000 with the
    starting parameters (issue 17, case 9)."""
    wi, wo, f_r, _ = _arrays(n=10)
    wo = wo.copy()
    wo[[3, 7], 2] *= -1
    path = write_table(tmp_path / f"t{suffix}", wi, wo, f_r)
    with pytest.raises(TableError, match=r"2 row\(s\) have wi or wo at or below the horizon .*first at row 3"):
        read_table(path)
