"""``neuenh scene plan``: it writes the plan, resumes after a kill, and answers bad input in one line."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from cli_runs import neuenh_here
from neuenh.files import is_temporary
from scene_files import scene, write_tables

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def tables(tmp_path_factory) -> Path:
    return write_tables(tmp_path_factory.mktemp("scene"))


def test_the_command_writes_the_plan_and_resumes_after_a_kill(tables, tmp_path):
    path = tmp_path / "scene.yaml"
    data = scene(tables, materials=[{"path": str(tables / n)} for n in ("gloss.npz", "retro.npz", "sheen.npz")])
    path.write_text(yaml.safe_dump(data))
    whole = neuenh_here("scene", "plan", path, "-o", tmp_path / "whole", "--chunk", "1", "--json")
    assert whole.returncode == 0, whole.stderr
    reference = json.loads((tmp_path / "whole" / "plan.json").read_text())
    assert [m["name"] for m in reference["materials"]] == ["gloss", "retro", "sheen"]
    assert {"plan", "richest", "cheapest"} <= set(reference["totals"])
    text = (tmp_path / "whole" / "plan.md").read_text()
    assert "| **the plan** |" in text and "stay analytical" in text
    assert (tmp_path / "whole" / "cost_vs_error.png").stat().st_size > 1000
    assert not (tmp_path / "whole" / "contact_sheet.png").exists()  # tables cannot be rendered

    out = tmp_path / "killed"
    proc = subprocess.Popen([sys.executable, "-m", "neuenh_service.cli.main", "scene", "plan", str(path), "-o", str(out),
                             "--chunk", "1"], cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 120
    def planned() -> list[Path]:  # kept materials, not the temporary file of one being written
        return [p for p in (out / "materials").glob("*.json") if not is_temporary(p)]

    while not planned():
        assert proc.poll() is None and time.monotonic() < deadline
        time.sleep(0.05)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    kept = len(planned())
    assert 1 <= kept < 3
    again = neuenh_here("scene", "plan", path, "-o", out, "--chunk", "1")  # the kill is the process's
    assert again.returncode == 0 and f"resuming: {kept} material(s) already planned" in again.stderr
    resumed = json.loads((out / "plan.json").read_text())
    for a, b in zip(resumed["materials"], reference["materials"]):
        assert (a["name"], a["chosen"], a["error"]) == (b["name"], b["chosen"], b["error"])


@pytest.mark.parametrize("args, message", [
    (["scene", "plan", "missing.yaml", "-o", "x"], "missing.yaml: no such file"),
    (["scene", "plan", "{list}", "-o", "x"], "a scene is a mapping, got list"),
])
def test_the_command_answers_bad_input_in_one_line(args, message, tmp_path):
    (tmp_path / "list.yaml").write_text("- a\n- b\n")
    result = neuenh_here(*[a.replace("{list}", str(tmp_path / "list.yaml")) for a in args])
    assert result.returncode == 2 and message in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1 and "Traceback" not in result.stderr
