"""What only the local-directory backend has: its file layout and the temp-file protocol."""

from __future__ import annotations

import hashlib
from pathlib import Path

import pytest

from neuenh_service.storage import ConflictError, LocalArtifactStore
from neuenh_service.storage.local import TEMP_PREFIX
from storage_kit import VERSIONS, WRITTEN_KEY, kill_a_writer_mid_write


def files(root: Path) -> list[str]:
    return sorted(p.relative_to(root).as_posix() for p in root.rglob("*") if p.is_file())


def test_layout_and_no_temp_files_left(tmp_path):
    store = LocalArtifactStore(tmp_path / "a")
    store.put("jobs/j/rounds/0000/checkpoint.safetensors", b"0")
    store.put("jobs/j/rounds/0000/checkpoint.safetensors", b"00")
    store.put("jobs/j/rounds/0001/checkpoint.safetensors", b"1")
    key = store.put_content(b"data")
    store.put_content(b"data")
    digest = hashlib.sha256(b"data").hexdigest()
    assert key == f"sha256/{digest[:2]}/{digest}"
    assert files(tmp_path / "a") == sorted(["jobs/j/rounds/0000/checkpoint.safetensors",
                                            "jobs/j/rounds/0001/checkpoint.safetensors", key])
    assert (tmp_path / "a" / key).stat().st_mode & 0o777 == 0o644


def test_put_content_writes_once(tmp_path):
    store = LocalArtifactStore(tmp_path)
    key = store.put_content(b"x" * 1000)
    before = (tmp_path / key).stat()
    store.put_content(b"x" * 1000)
    after = (tmp_path / key).stat()
    assert (before.st_ino, before.st_mtime_ns) == (after.st_ino, after.st_mtime_ns)


def test_a_key_cannot_be_both_file_and_directory(tmp_path):
    store = LocalArtifactStore(tmp_path)
    store.put("a/b", b"x")
    with pytest.raises(ConflictError, match="prefix"):
        store.put("a/b/c", b"y")
    with pytest.raises(ConflictError, match="under it"):
        store.put("a", b"y")
    assert store.get("a/b") == b"x" and files(tmp_path) == ["a/b"]


@pytest.mark.parametrize("delay_s", [0.05, 0.2])
def test_a_writer_killed_mid_write_leaves_old_or_new(tmp_path, delay_s):
    """SIGKILL a process that keeps rewriting an 8 MiB artifact: the key holds one whole version,
    and whatever the writer left behind is a temp file no key can name, which the sweep removes."""
    root = tmp_path / "store"
    kill_a_writer_mid_write(f"LocalArtifactStore({str(root)!r})", delay_s)
    store = LocalArtifactStore(root)
    data = store.get(WRITTEN_KEY)
    assert data in VERSIONS
    leftovers = [f for f in files(root) if f != WRITTEN_KEY]
    assert all(Path(f).name.startswith(TEMP_PREFIX) for f in leftovers)
    assert store.remove_stale_temp_files(older_than_s=3600) == 0  # young: maybe still being written
    assert store.remove_stale_temp_files(older_than_s=-1) == len(leftovers)
    assert files(root) == [WRITTEN_KEY] and store.get(WRITTEN_KEY) == data
