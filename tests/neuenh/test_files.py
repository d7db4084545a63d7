"""``neuenh.files.atomic_write``: whole files or none, unique temporaries, permissions, digests; and
``existing``: a name's status, or None for one that names nothing, however it fails.

Concurrent writers of one path each leave a whole file (the last rename wins) and no temporary; a
failing writer leaves the old content and no temporary; the mode is applied; the data reaches the
disk through fsync before the rename (checked by recording the calls).
"""

from __future__ import annotations

import hashlib
import os
import stat
import threading
from pathlib import Path

import pytest

from neuenh.files import atomic_write, atomic_write_digest, existing, is_temporary


def test_bytes_text_and_a_writer_function(tmp_path):
    assert atomic_write(tmp_path / "a.bin", b"\x00\x01").read_bytes() == b"\x00\x01"
    assert atomic_write(tmp_path / "a.txt", "grüße\n").read_text(encoding="utf-8") == "grüße\n"
    assert atomic_write(tmp_path / "c.txt", lambda p: Path(p).write_text("by the writer")).read_text() == "by the writer"
    assert sorted(os.listdir(tmp_path)) == ["a.bin", "a.txt", "c.txt"]


@pytest.mark.parametrize("mode", [0o644, 0o600, 0o640])
def test_the_mode_is_applied(tmp_path, mode):
    assert atomic_write(tmp_path / "f", b"x", mode=mode).stat().st_mode & 0o777 == mode


def test_the_digest_is_of_what_was_written(tmp_path):
    digest = atomic_write_digest(tmp_path / "f", lambda p: Path(p).write_bytes(b"payload" * 1000))
    assert digest == hashlib.sha256(b"payload" * 1000).hexdigest()


@pytest.mark.parametrize("how", ["bytes", "writer"])
def test_a_failed_write_leaves_the_old_file_and_no_temporary(tmp_path, how, monkeypatch):
    target = atomic_write(tmp_path / "f", b"old")
    if how == "bytes":
        monkeypatch.setattr(os, "replace", lambda *a: (_ for _ in ()).throw(OSError("disk gone")))
        data = b"new"
    else:
        def data(p):
            Path(p).write_bytes(b"half")
            raise RuntimeError("writer died")
    with pytest.raises((OSError, RuntimeError)):
        atomic_write(target, data)
    monkeypatch.undo()
    assert target.read_bytes() == b"old" and os.listdir(tmp_path) == ["f"]


def test_nothing_is_left_when_the_first_write_fails(tmp_path):
    with pytest.raises(ZeroDivisionError):
        atomic_write(tmp_path / "f", lambda p: 1 / 0)
    assert os.listdir(tmp_path) == []


def test_concurrent_writers_each_leave_a_whole_file(tmp_path):
    """Eight threads write different payloads to one path many times: every read sees one whole
    payload, and no temporary is left."""
    target = tmp_path / "shared.bin"
    payloads = [bytes([i]) * 200_000 for i in range(8)]
    atomic_write(target, payloads[0])
    seen, stop = [], threading.Event()

    def reader():
        while not stop.is_set():
            seen.append(target.read_bytes())

    def writer(payload):
        for _ in range(20):
            atomic_write(target, payload)

    threads = [threading.Thread(target=writer, args=(p,)) for p in payloads]
    watcher = threading.Thread(target=reader)
    watcher.start()
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    stop.set()
    watcher.join()
    assert seen and all(data in payloads for data in seen)
    assert target.read_bytes() in payloads and os.listdir(tmp_path) == ["shared.bin"]


def test_the_data_is_fsynced_before_the_rename_and_the_folder_after(tmp_path, monkeypatch):
    calls = []
    real_fsync, real_replace = os.fsync, os.replace
    monkeypatch.setattr(os, "fsync", lambda fd: (calls.append(("fsync", os.path.isdir(f"/proc/self/fd/{fd}"))),
                                                  real_fsync(fd)))
    monkeypatch.setattr(os, "replace", lambda a, b: (calls.append(("replace", None)), real_replace(a, b)))
    atomic_write(tmp_path / "f", b"durable")
    assert calls == [("fsync", False), ("replace", None), ("fsync", True)]


@pytest.mark.parametrize("name", ["gloss.json", "model", "bundle.tar.gz", ".hidden.json"])
def test_a_temporary_file_is_told_from_the_file_it_becomes(tmp_path, name):
    """What a writer killed mid-write leaves behind (``.<name>.<random>.tmp<suffix>``, matched by a
    glob of the target's suffix) is named temporary; the file it becomes is not."""
    seen = []
    atomic_write(tmp_path / name, lambda tmp: (seen.append(tmp), tmp.write_text("x")))
    assert is_temporary(seen[0]) and not is_temporary(tmp_path / name)


@pytest.mark.parametrize("name, kind", [
    ("a.bin", "file"), ("folder", "folder"), ("missing.bin", None), ("a.bin/below", None),  # ENOTDIR
    ("x" * 300 + ".npz", None), ("nul\x00.npz", None)])  # ENAMETOOLONG, and ValueError from the NUL
def test_existing_is_a_status_or_none_for_any_name(tmp_path, name, kind):
    (tmp_path / "a.bin").write_bytes(b"abc")
    (tmp_path / "folder").mkdir()
    status = existing(str(tmp_path / name))
    assert (status is None) == (kind is None)
    if kind == "file":
        assert status.st_size == 3
    if kind == "folder":
        assert stat.S_ISDIR(status.st_mode)
