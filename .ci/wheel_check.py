#!/usr/bin/env python3
"""The wheel as a user gets it, used as a user would, outside the checkout.

    python3 .ci/wheel_check.py [--keep]

1. builds the wheel from this checkout's files (tracked, and untracked unless ignored) copied to a
   temporary folder, so no build/ of an earlier layout leaks in;
2. checks what it holds: its top-level names are the project's own (ALLOWED), and it carries every
   file of models/ byte for byte as package data;
3. installs it into a fresh virtualenv outside the checkout — torch 2.13.0 first, as the Makefile does
   (a looser pin pulls CUDA), then the wheel with its export extra;
4. from a neutral folder, with no NEUENH_* variable set: ``neuenh fit --model enhanced-ggx`` on a
   generated table, ``neuenh export enhanced-ggx --format onnx`` of that fit, ``neuenh scene plan`` of
   a scene whose ladder is ``{rungs: enhanced-ggx}``, and ``neuenh serve`` with ``neuenh-client submit
   --wait`` of a tiny job, then ``neuenh-client download`` of its model and the dashboard's page.

Each step prints its time; the first failure ends the run (exit 1) and keeps the temporary folder.
Standard library only: it runs on the machine's python3 before anything is installed.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import urllib.request
import zipfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
TORCH = "torch==2.13.0"
ALLOWED = {"neuenh", "neuenh_service"}  # the science, the service's rooms (models: neuenh/shipped_models)
MODELS_IN_WHEEL = "neuenh/shipped_models"

GENERATE_TABLE = """
import sys
from neuenh.data.directions import sample_directions
from neuenh.data.synthetic import synthetic_ggx
from neuenh.data.table import write_table

[material] = synthetic_ggx(1, seed=3, noise_sigma=0.0)  # an anisotropic GGX material, no noise
wi, wo = sample_directions(1200, seed=0, near_mirror=0.3)
write_table(sys.argv[1], wi, wo, material.evaluate(wi, wo))
"""
SHIPPED_FROM = "import neuenh.pretrained as p; print(p.bundle_path('enhanced-ggx'))"
SCENE = {"materials": [{"path": "generated.npz"}], "ladder": [{"rungs": "enhanced-ggx"}],
         "tolerance": {"metric": "log_l1", "relative": 0.1},
         "fit": {"samples": 600, "test_samples": 600, "epochs": 20}}
JOB = {"name": "wheel-check", "search": {"radius": 1, "epochs_per_round": 1, "max_rounds": 1},
       "train": {"batch_size": 1000, "lr": 5.0e-3},
       "data": [{"source": "synthetic_zoo", "materials": 2, "samples": 300, "seed": 1}]}


class CheckFailed(Exception):
    pass


def run(argv, *, cwd: Path, env: dict | None = None, timeout: float = 900) -> str:
    done = subprocess.run([str(a) for a in argv], cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=timeout, stdin=subprocess.DEVNULL)
    if done.returncode != 0:
        raise CheckFailed(f"{' '.join(map(str, argv))} exited {done.returncode}:\n{done.stdout[-3000:]}\n"
                          f"{done.stderr[-3000:]}")
    return done.stdout


def sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


class WheelCheck:
    """The steps, in order, each raising ``CheckFailed``; everything lives under ``tmp``."""

    def __init__(self, tmp: Path):
        self.tmp, self.work, self.home = tmp, tmp / "work", tmp / "home"
        self.bin = tmp / "venv" / "bin"
        self.wheel: Path | None = None

    def steps(self):
        return [("build the wheel from a copy of the checkout's files", self.build),
                ("check the wheel's top-level names and its models", self.contents),
                ("install torch, then the wheel with its export extra, into a fresh virtualenv", self.install),
                ("neuenh fit --model enhanced-ggx on a generated table", self.fit),
                ("neuenh export enhanced-ggx --format onnx (the fitted material)", self.export),
                ("neuenh scene plan with the ladder {rungs: enhanced-ggx}", self.scene_plan),
                ("neuenh serve; neuenh-client submit --wait of a tiny job, download its model",
                 self.serve_and_submit)]

    def build(self) -> None:
        listed = run(["git", "ls-files", "--cached", "--others", "--exclude-standard", "-z"], cwd=REPO).split("\0")
        source = self.tmp / "source"
        for name in filter(None, listed):
            if (REPO / name).is_file():  # a deleted, unstaged file is gone
                (source / name).parent.mkdir(parents=True, exist_ok=True)
                shutil.copy2(REPO / name, source / name)
        run([sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps", "-w", self.tmp / "dist", source],
            cwd=self.tmp)
        [self.wheel] = (self.tmp / "dist").glob("neuenh-*.whl")
        print(f"    {self.wheel.name}: {self.wheel.stat().st_size / 1e6:.2f} MB")

    def contents(self) -> None:
        with zipfile.ZipFile(self.wheel) as z:
            names = [n for n in z.namelist() if not n.endswith("/")]
            top = sorted({n.split("/")[0] for n in names if ".dist-info/" not in n})
            shipped = {n[len(MODELS_IN_WHEEL) + 1:]: sha256(z.read(n)) for n in names
                       if n.startswith(MODELS_IN_WHEEL + "/")}
        print(f"    top-level names: {', '.join(top)} (allowed: {', '.join(sorted(ALLOWED))})")
        if set(top) - ALLOWED:
            raise CheckFailed(f"the wheel installs top-level names not its own: {sorted(set(top) - ALLOWED)}")
        tree = {p.relative_to(REPO / "models").as_posix(): sha256(p.read_bytes())
                for p in sorted((REPO / "models").rglob("*")) if p.is_file()}
        if shipped != tree:
            raise CheckFailed(f"{MODELS_IN_WHEEL} differs from models/: missing {sorted(set(tree) - set(shipped))}, "
                              f"extra {sorted(set(shipped) - set(tree))}, changed "
                              f"{sorted(k for k in set(tree) & set(shipped) if tree[k] != shipped[k])}")
        bundles = sorted({Path(k).parent.as_posix() for k in tree if k.endswith("model.json")})
        print(f"    {len(tree)} files under models/, byte for byte: {', '.join(bundles)}")

    def install(self) -> None:
        run([sys.executable, "-m", "venv", self.bin.parent], cwd=self.tmp)
        pip = [self.bin / "python", "-m", "pip", "install", "--quiet"]
        run([*pip, "--upgrade", "pip"], cwd=self.tmp)
        run([*pip, TORCH], cwd=self.tmp)
        run([*pip, f"{self.wheel}[export]"], cwd=self.tmp)
        for folder in (self.work, self.home):
            folder.mkdir()

    def env(self) -> dict[str, str]:
        """A user's shell with the virtualenv activated: nothing of this checkout or its settings."""
        keep = {k: v for k, v in os.environ.items()
                if not k.startswith(("NEUENH_", "RAY_", "PYTHON", "VIRTUAL_ENV", "CONDA"))}
        return {**keep, "PATH": f"{self.bin}{os.pathsep}{keep.get('PATH', '')}", "HOME": str(self.home),
                "VIRTUAL_ENV": str(self.bin.parent)}

    def user(self, *argv, timeout: float = 900) -> str:
        """``argv`` run from the neutral folder, its program from the virtualenv."""
        return run([self.bin / argv[0], *argv[1:]], cwd=self.work, env=self.env(), timeout=timeout)

    def fit(self) -> None:
        found = Path(self.user("python", "-c", SHIPPED_FROM).strip())
        if self.bin.parent not in found.parents:
            raise CheckFailed(f"enhanced-ggx was found at {found}, not in the virtualenv's package data")
        print(f"    enhanced-ggx from {found}")
        self.user("python", "-c", GENERATE_TABLE, "generated.npz")
        report = json.loads(self.user("neuenh", "fit", "--model", "enhanced-ggx", "generated.npz", "--json",
                                      "--epochs", "30"))
        (self.work / "fit.json").write_text(json.dumps(report))
        [material] = report["materials"]
        if set(report["state"]) == {"0"} or not math.isfinite(material["loss"]):
            raise CheckFailed(f"not a fit of the enhanced model: state {report['state']}, loss {material['loss']}")
        print(f"    state {report['state']}, log-L1 {material['loss']:.4f}")

    def export(self) -> None:
        self.user("neuenh", "export", "enhanced-ggx", "--params", "fit.json", "--format", "onnx", "-o", "onnx")
        written = sorted(p.name for p in (self.work / "onnx").rglob("*.onnx") if p.stat().st_size > 0)
        if not written:
            raise CheckFailed("neuenh export wrote no ONNX file")
        print(f"    {', '.join(written)}")

    def scene_plan(self) -> None:
        (self.work / "scene.yaml").write_text(json.dumps(SCENE))  # JSON is YAML
        self.user("neuenh", "scene", "plan", "scene.yaml", "-o", "plan", "--no-sheet")
        plan = json.loads((self.work / "plan" / "plan.json").read_text())
        tried = [r["rung"] for r in plan["materials"][0]["results"]]
        print(f"    {len(tried)} rungs of enhanced-ggx fitted, chosen: {plan['materials'][0]['chosen']}")

    def serve_and_submit(self) -> None:
        (self.work / "job.yaml").write_text(json.dumps(JOB))
        log = self.work / "serve.log"
        with open(log, "wb") as out:
            server = subprocess.Popen([self.bin / "neuenh", "serve", "--port", "0", "--data-dir", "served"],
                                      cwd=self.work, env=self.env(), stdout=out, stderr=subprocess.STDOUT,
                                      stdin=subprocess.DEVNULL, start_new_session=True)
        try:
            url = wait_for_service(server, log)
            job_id = self.user("neuenh-client", "submit", "job.yaml", "--wait", "--url", url, timeout=600).strip()
            job = json.loads(self.user("neuenh-client", "status", job_id, "--json", "--url", url))
            self.user("neuenh-client", "download", job_id, "-o", "model.zip", "--url", url)
            with zipfile.ZipFile(self.work / "model.zip") as model, urllib.request.urlopen(url + "/") as page:
                files, dashboard = sorted(model.namelist()), page.read().decode()
            if "model.json" not in files or "<html" not in dashboard.lower():
                raise CheckFailed(f"the model's zip holds {files}; the dashboard page: {dashboard[:200]!r}")
            print(f"    {url}: job {job_id} {job['status']}, its model downloaded ({', '.join(files)}), "
                  f"the dashboard served")
        finally:
            server.send_signal(signal.SIGTERM)  # it stops the job at a safe point and shuts Ray down
            try:
                server.wait(90)
            except subprocess.TimeoutExpired:
                os.killpg(server.pid, signal.SIGKILL)
                server.wait()
                raise CheckFailed(f"neuenh serve did not stop on SIGTERM within 90 s:\n{log.read_text()[-2000:]}")
        # uvicorn re-raises the SIGTERM it handled once shut down: -15 is a clean stop too
        if server.returncode not in (0, -signal.SIGTERM) or "Application shutdown complete" not in log.read_text():
            raise CheckFailed(f"neuenh serve did not stop cleanly ({server.returncode}):\n{log.read_text()[-2000:]}")


def wait_for_service(server: subprocess.Popen, log: Path, timeout: float = 180) -> str:
    """The URL ``neuenh serve`` announces in its log, once ``/v1/health`` answers."""
    deadline, url = time.monotonic() + timeout, None
    while time.monotonic() < deadline:
        if server.poll() is not None:
            raise CheckFailed(f"neuenh serve exited {server.returncode}:\n{log.read_text()[-2000:]}")
        if url is None:
            announced = re.search(r"dashboard (http://\S+?)/ ", log.read_text())
            url = announced.group(1) if announced else None
        else:
            try:
                with urllib.request.urlopen(url + "/v1/health", timeout=5) as answer:
                    if answer.status == 200:
                        return url
            except OSError:
                pass
        time.sleep(0.5)
    raise CheckFailed(f"neuenh serve did not answer within {timeout:.0f} s:\n{log.read_text()[-2000:]}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--keep", action="store_true", help="keep the temporary folder (wheel, virtualenv, outputs)")
    args = parser.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="neuenh-wheel-check-"))
    assert REPO not in tmp.parents, "the check runs outside the checkout"
    start, passed, failed = time.monotonic(), 0, 0
    for title, check in WheelCheck(tmp).steps():
        print(f"--- {title}", flush=True)
        began = time.monotonic()
        try:
            check()
        except (CheckFailed, subprocess.TimeoutExpired) as exc:
            print(f"    FAILED after {time.monotonic() - began:.1f} s: {exc}", flush=True)
            failed = 1
            break
        print(f"    ok in {time.monotonic() - began:.1f} s", flush=True)
        passed += 1
    if failed or args.keep:
        print(f"kept {tmp}")
    else:
        shutil.rmtree(tmp, ignore_errors=True)
    print(f"took {time.monotonic() - start:.0f} s")
    print(f"wheel-check: {passed} passed, {failed} failed")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
