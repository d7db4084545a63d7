"""``api.uploads``: files received by content (the same content is one file, and a refused request
removes only what it alone kept) and a plan's files released once no unfinished plan names them."""

from __future__ import annotations

import hashlib
import io
import threading

import pytest
from fastapi import HTTPException, UploadFile

from neuenh_service.api.uploads import PlanUploads, discard, receive
from neuenh.data.table import read_table
from scene_files import write_tables
from neuenh_service.storage import SQLitePlanStore


@pytest.fixture(scope="module")
def tables(tmp_path_factory):
    return write_tables(tmp_path_factory.mktemp("tables"))


def sent(tables, *names):
    return [UploadFile(io.BytesIO((tables / n).read_bytes()), filename=f"some/folder/{n}") for n in names]


def read(path, name):
    return read_table(path, name=name, max_rows=10_000)


def test_the_same_content_is_one_file_and_discard_removes_only_what_a_request_kept(tables, tmp_path):
    first = receive(sent(tables, "gloss.npz"), tmp_path, read, 10_000)
    second = receive(sent(tables, "gloss.npz", "retro.npz"), tmp_path, read, 10_000)
    digest = hashlib.sha256((tables / "gloss.npz").read_bytes()).hexdigest()
    assert [(r.filename, r.name, r.path.name, r.new) for r in first] == [("gloss.npz", "gloss", digest, True)]
    assert [r.new for r in second] == [False, True] and second[0].path == first[0].path
    assert second[0].value.names == ("gloss",) and len(second[1].value) == 1600
    discard(second)
    assert sorted(p.name for p in tmp_path.iterdir()) == [digest]  # retro's went, gloss's stays (first's)


def test_an_unreadable_upload_keeps_nothing_of_its_request(tables, tmp_path):
    files = sent(tables, "gloss.npz") + [UploadFile(io.BytesIO(b"wi_x,wo_y\n1,2\n"), filename="bad.csv")]
    with pytest.raises(HTTPException) as info:
        receive(files, tmp_path, read, 10_000)
    assert info.value.status_code == 422 and info.value.detail.startswith("bad.csv: ")
    assert list(tmp_path.iterdir()) == []  # the good table sent beside it went too, and no partial file
    with pytest.raises(HTTPException, match="1600 measurements exceed this service's limit of 1000"):
        receive(sent(tables, "retro.npz"), tmp_path, lambda p, n: read_table(p, n, max_rows=1000), 1000)
    assert list(tmp_path.iterdir()) == []


def test_a_plans_files_are_released_once_no_unfinished_plan_names_them(tables, tmp_path):
    folder = tmp_path / "uploads"
    [gloss, retro] = receive(sent(tables, "gloss.npz", "retro.npz"), folder, read, 10_000)
    scene = lambda *kept: {"materials": [{"path": str(k.path)} for k in kept] + [{"path": str(tables / "sheen.npz")}],
                           "ladder": ["ggx"], "tolerance": {"relative": 0.1}}  # noqa: E731
    plans = SQLitePlanStore(tmp_path / "jobs.sqlite")
    a, _ = plans.create_plan(scene(gloss, retro))
    b, _ = plans.create_plan(scene(gloss))  # queued: it still needs gloss
    uploads = PlanUploads(folder, threading.Lock())
    assert uploads.named_by(a) == {gloss.path, retro.path}  # not sheen: it lies elsewhere
    assert uploads.release(plans.fail(a.id, "for the test"), plans) == [retro.path]
    assert sorted(p.name for p in folder.iterdir()) == [gloss.path.name]
    assert uploads.release(plans.fail(b.id, "for the test"), plans) == [gloss.path]
    assert list(folder.iterdir()) == []
    plans.close()


def test_a_start_sweeps_what_no_unfinished_plan_names(tables, tmp_path):
    folder = tmp_path / "uploads"
    [gloss, retro] = receive(sent(tables, "gloss.npz", "retro.npz"), folder, read, 10_000)
    (folder / ".upload-cut-off").write_bytes(b"half a file")  # a request that died mid-upload
    plans = SQLitePlanStore(tmp_path / "jobs.sqlite")
    plans.create_plan({"materials": [{"path": str(gloss.path)}], "ladder": ["ggx"], "tolerance": {"relative": 0.1}})
    gone = PlanUploads(folder, threading.Lock()).sweep(plans)
    assert sorted(p.name for p in gone) == sorted([".upload-cut-off", retro.path.name])
    assert [p.name for p in folder.iterdir()] == [gloss.path.name]
    plans.close()
