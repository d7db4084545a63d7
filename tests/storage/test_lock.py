"""The owner lock: one process runs a store's jobs; the second is told who owns it; a crash of the
owner frees the store at once."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap

import pytest

from neuenh_service.storage import OwnerLock, StorageError, StoreLockedError


def test_second_owner_is_refused_with_the_first_ones_name(tmp_path):
    with OwnerLock(tmp_path / "owner.lock", owner="neuenh serve"):
        with pytest.raises(StoreLockedError) as refused:
            OwnerLock(tmp_path / "owner.lock", owner="neuenh search").acquire()
    message = str(refused.value)
    assert isinstance(refused.value, StorageError)
    assert f"neuenh serve (pid {os.getpid()}" in message and str(tmp_path) in message
    assert "\n" not in message


def test_release_frees_the_store(tmp_path):
    first = OwnerLock(tmp_path / "owner.lock", owner="a").acquire()
    assert first.held
    first.release()
    assert not first.held
    with OwnerLock(tmp_path / "owner.lock", owner="b") as second:
        assert second.held


@pytest.mark.parametrize("death", [signal.SIGKILL, signal.SIGTERM])
def test_a_dead_owner_leaves_no_stale_lock(tmp_path, death):
    holder = subprocess.Popen([sys.executable, "-c", textwrap.dedent(f"""
        import sys, time
        from neuenh_service.storage import OwnerLock
        OwnerLock({str(tmp_path / 'owner.lock')!r}, owner="crasher").acquire()
        print("held", flush=True)
        time.sleep(60)
    """)], stdout=subprocess.PIPE, text=True, cwd=os.getcwd())
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(StoreLockedError, match=f"crasher \\(pid {holder.pid}"):
            OwnerLock(tmp_path / "owner.lock", owner="me").acquire()
    finally:
        holder.send_signal(death)
        holder.wait(10)
    with OwnerLock(tmp_path / "owner.lock", owner="me") as lock:
        assert lock.held
