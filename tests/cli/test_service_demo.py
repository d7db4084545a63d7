"""``make demo``'s script end to end on a tiny spec: neuenh serve with real Ray, neuenh-client
submit --wait, history, download, the fair plain-GGX comparison, and a clean stop; run again, it
shows the same job."""

from __future__ import annotations

import re
import subprocess
import sys

import yaml

from jobspecs import tiny_spec
from neuenh.checkpoint import Bundle
from serve_process import REPO, clean_env


def demo(tmp_path):
    spec = tmp_path / "tiny.yaml"
    spec.write_text(yaml.safe_dump(tiny_spec(max_rounds=2).model_dump(mode="json")))
    run = subprocess.run([sys.executable, REPO / "examples" / "service_demo.py", "--spec", spec,
                          "--data-dir", tmp_path / "demo"], capture_output=True, text=True, cwd=REPO,
                         env=clean_env(), timeout=300)
    assert run.returncode == 0, run.stdout + run.stderr
    return run


def test_service_demo_runs_the_whole_stack_and_again_shows_the_same_job(tmp_path):
    run = demo(tmp_path)
    out = run.stdout
    assert "dashboard http://127.0.0.1:" in out and "service stopped" in out
    assert "round 0: committed" in run.stderr  # submit --wait's progress
    assert "Traceback" not in out + run.stderr
    [job] = [p.name for p in (tmp_path / "demo" / "results").iterdir()]
    bundle = Bundle.load(tmp_path / "demo" / "results" / job / "model")
    assert f"final state  {bundle.model.state}" in out
    enhanced, plain, words = re.search(r"val log-L1 +(\S+) after 2 epochs; training plain GGX the same 2 epochs \.\.\. "
                                       r"(\S+)\n +-> (.*)\n", out).groups()
    if enhanced != plain:  # printed to 5 digits: the words must go the way the numbers do
        assert words.startswith("the enhancement lowers" if float(enhanced) < float(plain) else
                                "the enhancement does not lower"), words
    assert (tmp_path / "demo" / "results" / job / "history.json").exists()
    assert not (tmp_path / "demo" / "owner.lock").read_text(), "the service released its store"

    again = demo(tmp_path)  # the same submission key: the finished job is shown, not trained again
    assert "already submitted" in again.stderr and "round 0: committed" in again.stderr
    assert [p.name for p in (tmp_path / "demo" / "results").iterdir()] == [job]
