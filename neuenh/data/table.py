"""A user's own measurements as a table, one material per file: ``.npz`` or CSV text.

**npz**: arrays ``wi``, ``wo``, ``f_r`` (each ``(n, 3)``, any real numeric dtype) and an optional
``weight`` ``(n,)``.

**CSV** (UTF-8 text; recognised by its header, whatever the file's extension): one header line,
then one row per measurement, comma-separated. Lines starting with ``#`` and blank lines are
skipped (before the header too), so a file may begin with comments about its origin::

    # brushed aluminium, gonioreflectometer run 2024-05-02
    wi_x,wi_y,wi_z,wo_x,wo_y,wo_z,r,g,b,weight
    0.0,0.0,1.0,0.3,0.0,0.953939,0.081,0.079,0.077,1.0

=========================  ===============================================================
columns                    meaning
=========================  ===============================================================
``wi_x, wi_y, wi_z``       incident (light) direction, unit vector in the local frame
``wo_x, wo_y, wo_z``       outgoing (view) direction, unit vector in the local frame
``r, g, b``                f_r in RGB, **without** the cosine factor (1/sr)
``weight`` (optional)      a non-negative confidence of the row (e.g. 1/variance)
=========================  ===============================================================

Column names are case-insensitive and may come in any order; the nine required ones must all be
present, and no other column is allowed (a typo would otherwise be silently ignored).

Both formats are validated the same way — unit directions (|norm - 1| <= 1e-3) above the horizon
(z > 0), finite values within float32's range (what the models compute in), ``f_r`` and ``weight``
non-negative, matching lengths, at least one row, at most the reader's ``max_rows`` (an npz's from
its headers, before inflating; a CSV's counted as it streams) — and every problem is a
``TableError`` naming the file, the row (0-based, the same in both formats; CSV errors add the
1-based line of the file) and what is wrong. ``load_table`` returns a checked table as ``Samples``;
``check_table`` only checks it, with numpy alone (``neuenh-client fit`` checks tables before
uploading them without importing torch).

**Weights.** ``Samples`` has no weight field and training does not weight the loss, so a table's
weights are not used by training or fitting today. They are validated, kept as ``Table.weight``
and carried by the material ``load_measured`` returns (``TableMaterial.weight``, with a summary in
its ``metadata["weight"]``), ready for a weighted loss; ``neuenh data inspect`` reports them.
"""

from __future__ import annotations

import csv
import os
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..files import atomic_write
from .errors import DataError, check_file

if TYPE_CHECKING:  # torch is imported where a table becomes Samples: checking a table needs only numpy
    import torch

    from .samples import Samples

CSV_COLUMNS = ("wi_x", "wi_y", "wi_z", "wo_x", "wo_y", "wo_z", "r", "g", "b")
WEIGHT = "weight"
_KEYS = ("wi", "wo", "f_r")
_UNIT_TOLERANCE = 1e-3
_FLOAT32_MAX = float(np.finfo(np.float32).max)
_ZIP_MAGIC = (b"PK\x03\x04", b"PK\x05\x06")


class TableError(DataError):
    """A measurement table that cannot be used; the message names the file and the problem."""


class TableTooLarge(TableError):
    """A table with more rows than the reader was allowed (``max_rows``): ``rows`` of them, or None
    when it was refused at its first row beyond the limit (a CSV, counted as it is read)."""

    def __init__(self, path: Path, rows: int | None, max_rows: int):
        self.rows, self.max_rows = rows, max_rows
        super().__init__(f"{path}: {self.counted} rows exceed the limit of {max_rows}")

    @property
    def counted(self) -> str:
        return str(self.rows) if self.rows is not None else f"more than {self.max_rows}"


@dataclass
class Table:
    """A table's measurements (one material), its optional per-row weights, and its format."""

    samples: Samples
    weight: torch.Tensor | None  # (n,) float32, or None when the table has no weight column
    format: str  # "npz" or "csv"


# -- detection -------------------------------------------------------------------------------
def _first_line(text: str) -> str | None:
    for line in text.splitlines():
        stripped = line.strip()
        if stripped and not stripped.startswith("#"):
            return stripped
    return None


def looks_like_csv_table(head: bytes) -> bool:
    """Whether a file starting with ``head`` is a CSV table: UTF-8 text whose first line that is
    neither blank nor a comment is a header naming ``wi_x`` (the other columns are checked when
    reading, so a header with a typo gets a precise error rather than "unrecognised")."""
    if b"\0" in head:
        return False
    text = head.decode("utf-8", errors="ignore").lstrip("\ufeff")
    line = _first_line(text)
    if line is None:
        return False
    return "wi_x" in [c.strip().strip('"').lower() for c in line.split(",")]


def looks_like_table(path: str | os.PathLike) -> bool:
    """Whether the file at ``path`` may be a table by its first bytes — a zip archive (every ``.npz``,
    a table's or another's, such as NBRDF weights) or a CSV table — read without numpy's arrays or
    torch; False for anything else (an RGL or MERL file) or a file that cannot be read."""
    try:
        with open(path, "rb") as f:
            head = f.read(4096)
    except OSError:
        return False
    return head[:4] in _ZIP_MAGIC or looks_like_csv_table(head)


# -- reading ---------------------------------------------------------------------------------
def load_table(path: str | os.PathLike, name: str | None = None, max_rows: int | None = None) -> Table:
    """The table at ``path`` (npz or CSV, told apart by content); ``name`` defaults to the stem.
    ``max_rows``: refuse a larger table before reading its values (an npz's row counts come from
    its arrays' headers, before anything is decompressed)."""
    import torch

    from .samples import Samples

    path, arrays, fmt = _checked(path, max_rows)
    t = {k: torch.as_tensor(np.asarray(arrays[k]), dtype=torch.float32) for k in _KEYS}
    weight = torch.as_tensor(np.asarray(arrays[WEIGHT]), dtype=torch.float32) if WEIGHT in arrays else None
    samples = Samples(t["wi"], t["wo"], t["f_r"], torch.zeros(len(t["wi"]), dtype=torch.long),
                      (path.stem if name is None else name,))
    return Table(samples, weight, fmt)


def check_table(path: str | os.PathLike, max_rows: int | None = None) -> int:
    """The number of rows of the table at ``path`` once it is validated as ``load_table`` validates
    it (a ``TableError`` otherwise), without building ``Samples``: numpy only, no torch."""
    return len(_checked(path, max_rows)[1]["wi"])


def _checked(path: str | os.PathLike, max_rows: int | None) -> tuple[Path, dict[str, np.ndarray], str]:
    """The validated arrays of the table at ``path`` and its format ("npz" or "csv")."""
    path = check_file(path, TableError)
    try:
        with open(path, "rb") as f:
            head = f.read(4)
    except OSError as exc:
        raise TableError(f"{path}: cannot be read ({exc.strerror or exc})") from None
    if head in _ZIP_MAGIC:
        arrays, fmt = _read_npz(path, max_rows), "npz"
    else:
        arrays, fmt = _read_csv(path, max_rows), "csv"
    _validate(path, arrays)
    return path, arrays, fmt


def read_table(path: str | os.PathLike, name: str | None = None, max_rows: int | None = None) -> Samples:
    """The measurements of the table at ``path`` (npz or CSV) as one material's ``Samples``."""
    return load_table(path, name, max_rows).samples


def _too_many(path: Path, rows: int, max_rows: int | None) -> None:
    if max_rows is not None and rows > max_rows:
        raise TableTooLarge(path, rows, max_rows)


def _check_npz_headers(path: Path, max_rows: int | None) -> None:
    """Read only the .npy headers of the table's arrays: their shapes against ``max_rows``, and
    the bytes they claim against the bytes the archive holds (a header claiming 10^12 rows, or a
    few MB of deflated zeros that inflate to GBs, is refused before any array is decompressed)."""
    try:
        with zipfile.ZipFile(path) as archive:
            for info in archive.infolist():
                key = info.filename.removesuffix(".npy")
                if key not in (*_KEYS, WEIGHT):
                    continue
                with archive.open(info) as member:
                    try:
                        version = np.lib.format.read_magic(member)
                    except ValueError:
                        raise TableError(f"{path}: {key} is not an array") from None
                    read_header = (np.lib.format.read_array_header_1_0 if version == (1, 0)
                                   else np.lib.format.read_array_header_2_0)
                    shape, _, dtype = read_header(member)
                    header_bytes = member.tell()
                if not shape:
                    continue  # a scalar: the shape checks after loading name it
                _too_many(path, int(shape[0]), max_rows)
                claimed = int(np.prod(shape, dtype=object)) * dtype.itemsize
                if claimed + header_bytes > info.file_size:
                    raise TableError(f"{path}: {key}'s header claims shape {tuple(shape)} ({claimed} bytes) but "
                                     f"the archive holds {info.file_size - header_bytes} bytes of it")
    except TableError:
        raise
    except (ValueError, OSError, zipfile.BadZipFile, EOFError) as exc:
        raise TableError(f"{path}: not a readable .npz table ({exc})") from None


def _read_npz(path: Path, max_rows: int | None = None) -> dict[str, np.ndarray]:
    _check_npz_headers(path, max_rows)
    try:
        with np.load(path, allow_pickle=False) as npz:
            arrays = {k: npz[k] for k in npz.files if k in (*_KEYS, WEIGHT)}
    except (ValueError, OSError, zipfile.BadZipFile, EOFError) as exc:
        raise TableError(f"{path}: not a readable .npz table ({exc})") from None
    missing = [k for k in _KEYS if k not in arrays]
    if missing:
        raise TableError(f"{path}: missing array(s) {missing} (a table needs wi, wo, f_r)")
    for key, a in arrays.items():
        if not isinstance(a, np.ndarray):  # a member that is not a .npy array comes back as bytes
            raise TableError(f"{path}: {key} is not an array")
        if not (np.issubdtype(a.dtype, np.floating) or np.issubdtype(a.dtype, np.integer)):
            shape = "(n,)" if key == WEIGHT else "(n, 3)"
            raise TableError(f"{path}: {key} must be a numeric {shape} array, got {a.dtype}{a.shape}")
    for key in _KEYS:
        a = arrays[key]
        if a.ndim != 2 or a.shape[1] != 3:
            raise TableError(f"{path}: {key} must be a numeric (n, 3) array, got {a.dtype}{a.shape}")
    if WEIGHT in arrays and arrays[WEIGHT].ndim != 1:
        raise TableError(f"{path}: weight must be a numeric (n,) array, got {arrays[WEIGHT].dtype}{arrays[WEIGHT].shape}")
    return arrays


def _csv_lines(path: Path):
    """(1-based line number, text) of every line that is neither blank nor a comment, streamed from
    the file: only one line is held at a time (a non-UTF-8 byte is named by its offset in the file)."""
    offset = 0
    try:
        with open(path, "rb") as f:
            for line_no, raw in enumerate(f, start=1):
                try:
                    line = raw.decode("utf-8")
                except UnicodeDecodeError as exc:
                    raise TableError(f"{path}: not a CSV table (not UTF-8 text: byte {offset + exc.start} is "
                                     f"{raw[exc.start:exc.start + 1]!r})") from None
                offset += len(raw)
                if line_no == 1:
                    line = line.lstrip("\ufeff")
                stripped = line.strip()
                if stripped and not stripped.startswith("#"):
                    yield line_no, line.rstrip("\r\n")
    except OSError as exc:
        raise TableError(f"{path}: cannot be read ({exc.strerror or exc})") from None


_CSV_CHUNK = 1 << 13  # rows parsed at once: their text is held only until they are numbers


def _read_csv(path: Path, max_rows: int | None = None) -> dict[str, np.ndarray]:
    """The CSV table's columns, read in one streaming pass: rows are counted as they come (a table
    over ``max_rows`` is refused at its first row beyond the limit) and turned into numbers a chunk at
    a time, so memory holds the values, never the file's text split into line objects."""
    lines = _csv_lines(path)
    first = next(lines, None)
    if first is None:
        raise TableError(f"{path}: the table is empty (no header line {','.join(CSV_COLUMNS)})")
    header_line, header_text = first
    header = [c.strip().strip('"').lower() for c in next(csv.reader([header_text]))]
    duplicates = sorted({c for c in header if header.count(c) > 1})
    if duplicates:
        raise TableError(f"{path}: line {header_line}: header repeats column(s) {duplicates}")
    missing = [c for c in CSV_COLUMNS if c not in header]
    if missing:
        raise TableError(f"{path}: line {header_line}: header lacks column(s) {missing} (a CSV table needs "
                         f"{','.join(CSV_COLUMNS)}[,{WEIGHT}])")
    unknown = [c for c in header if c not in (*CSV_COLUMNS, WEIGHT)]
    if unknown:
        raise TableError(f"{path}: line {header_line}: unknown column(s) {unknown} (allowed: "
                         f"{','.join(CSV_COLUMNS)},{WEIGHT})")
    width = len(header)
    chunks: list[np.ndarray] = []
    line_numbers: list[int] = []
    pending: list[tuple[int, str]] = []
    for line in lines:
        if max_rows is not None and len(line_numbers) + len(pending) >= max_rows:
            raise TableTooLarge(path, None, max_rows)
        pending.append(line)
        if len(pending) == _CSV_CHUNK:
            chunks.append(_csv_values(path, pending, header, len(line_numbers)))
            line_numbers += [n for n, _ in pending]
            pending = []
    if pending:
        chunks.append(_csv_values(path, pending, header, len(line_numbers)))
        line_numbers += [n for n, _ in pending]
    values = np.concatenate(chunks) if chunks else np.zeros((0, width))
    index = {c: header.index(c) for c in header}
    arrays = {
        "wi": values[:, [index[c] for c in CSV_COLUMNS[0:3]]],
        "wo": values[:, [index[c] for c in CSV_COLUMNS[3:6]]],
        "f_r": values[:, [index[c] for c in CSV_COLUMNS[6:9]]],
    }
    if WEIGHT in index:
        arrays[WEIGHT] = values[:, index[WEIGHT]]
    arrays["_lines"] = np.array(line_numbers, dtype=np.int64)
    return arrays


def _csv_values(path: Path, lines: list[tuple[int, str]], header: list[str], first_row: int) -> np.ndarray:
    """The numbers of a chunk of data lines (rows ``first_row``, ...), as float64 (rows, columns)."""
    rows = list(csv.reader(text for _, text in lines))
    width = len(header)
    for row_index, ((line_no, _), row) in enumerate(zip(lines, rows), start=first_row):
        if len(row) != width:
            raise TableError(f"{path}: row {row_index} (line {line_no}): {len(row)} values, the header has {width}")
    try:
        return np.array(rows, dtype=np.float64).reshape(len(rows), width)
    except ValueError:
        for row_index, ((line_no, _), row) in enumerate(zip(lines, rows), start=first_row):
            for column, cell in zip(header, row):
                try:
                    float(cell)
                except ValueError:
                    raise TableError(f"{path}: row {row_index} (line {line_no}): {column} is not a number "
                                     f"({cell.strip()!r})") from None
        raise  # pragma: no cover - numpy refused a value float() accepts


def _validate(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """Every check of the module doc, on the arrays a reader returned (its ``_lines`` taken off)."""
    lines = arrays.pop("_lines", None)

    def where(row: int) -> str:
        return f"row {row} (line {int(lines[row])})" if lines is not None else f"row {row}"

    keys = [*_KEYS, *([WEIGHT] if WEIGHT in arrays else [])]
    lengths = [arrays[k].shape[0] for k in keys]
    if len(set(lengths)) != 1:
        raise TableError(f"{path}: {', '.join(keys)} must have the same length, got "
                         f"{', '.join(str(n) for n in lengths)}")
    n = lengths[0]
    if n == 0:
        raise TableError(f"{path}: the table is empty")
    for key in keys:
        a = arrays[key]
        finite = np.isfinite(a)
        if not finite.all():
            row = int(np.argwhere(~finite)[0, 0])
            raise TableError(f"{path}: {key} has non-finite values (first at {where(row)})")
        # The samples are float32: a finite float64 beyond its range would be inf there, and a fit
        # on it would return its initial parameters with a null loss instead of an error.
        beyond = np.abs(a) > _FLOAT32_MAX
        if beyond.any():
            row = int(np.argwhere(beyond)[0, 0])
            raise TableError(f"{path}: {key} has values beyond float32's range of 3.4e38, which the models "
                             f"compute in (first at {where(row)})")
    for key in ("wi", "wo"):
        norms = np.linalg.norm(np.asarray(arrays[key], dtype=np.float64), axis=1)
        bad = np.abs(norms - 1) > _UNIT_TOLERANCE
        if bad.any():
            row = int(np.argmax(bad))
            raise TableError(f"{path}: {key} must hold unit vectors ({where(row)} has norm {norms[row]:.4g})")
    below = (np.asarray(arrays["wi"])[:, 2] <= 0) | (np.asarray(arrays["wo"])[:, 2] <= 0)
    if below.any():  # f_r is 0 there by definition: such rows would fit any parameters perfectly
        row = int(np.argmax(below))
        raise TableError(f"{path}: {int(below.sum())} row(s) have wi or wo at or below the horizon (z <= 0; "
                         f"first at {where(row)}); a BRDF is measured above it")
    for key in ("f_r", *([WEIGHT] if WEIGHT in arrays else [])):
        negative = arrays[key] < 0
        if negative.any():
            row = int(np.argwhere(negative)[0, 0])
            raise TableError(f"{path}: {key} has negative values (first at {where(row)})")
    if WEIGHT in arrays and not (arrays[WEIGHT] > 0).any():
        raise TableError(f"{path}: weight is zero on every row")


# -- writing ---------------------------------------------------------------------------------
def write_table(path: str | os.PathLike, wi, wo, f_r, weight=None) -> Path:
    """Write a table that ``read_table`` reads, atomically: CSV when ``path`` ends in ``.csv``
    (float32 values printed exactly, 9 significant digits), else ``.npz`` (float32 arrays)."""
    path = Path(path)
    arrays = {k: _float32(v) for k, v in (("wi", wi), ("wo", wo), ("f_r", f_r))}
    if weight is not None:
        arrays[WEIGHT] = _float32(weight).reshape(-1)
    if path.suffix.lower() == ".csv":
        columns = [arrays["wi"], arrays["wo"], arrays["f_r"]]
        header = ",".join(CSV_COLUMNS)
        if WEIGHT in arrays:
            columns.append(arrays[WEIGHT][:, None])
            header += f",{WEIGHT}"
        return atomic_write(path, lambda tmp: np.savetxt(tmp, np.concatenate(columns, axis=1), delimiter=",",
                                                         fmt="%.9g", header=header, comments=""))
    return atomic_write(path, lambda tmp: savez(tmp, arrays))


def _float32(values) -> np.ndarray:
    """``values`` (a torch tensor, an array or nested lists) as a float32 numpy array."""
    if hasattr(values, "detach"):  # a torch tensor, perhaps requiring grad (torch itself not needed here)
        values = values.detach().cpu().numpy()
    return np.asarray(values, dtype=np.float32)


def savez(path: Path, arrays) -> None:
    """``np.savez`` to exactly ``path``: through a file object, as ``np.savez`` adds ``.npz`` to a
    file name without it."""
    with open(path, "wb") as f:
        np.savez(f, **arrays)
