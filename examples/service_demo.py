"""``make demo``: the whole stack on the embedded default, as a new user would run it.

1. ``neuenh serve`` on 127.0.0.1 (a free port), embedded Ray, SQLite and artifacts in runs/demo;
2. ``neuenh-client submit examples/quickstart.yaml --wait``: the progress of every round, while the
   dashboard URL printed first shows the same search live;
3. ``neuenh-client history`` and ``download``: the path through the hypercube and the model;
4. the service is stopped with SIGTERM, as an operator would (Ray shuts down with it).

The submission carries an idempotency key, so running ``make demo`` again shows the same job
(resumed if it was interrupted) instead of training a second one; ``--new`` starts another.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import httpx

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data-dir", type=Path, default=ROOT / "runs" / "demo")
    parser.add_argument("--spec", type=Path, default=ROOT / "examples" / "quickstart.yaml")
    parser.add_argument("--new", action="store_true", help="submit a new job even if the demo ran before")
    args = parser.parse_args()
    args.data_dir.mkdir(parents=True, exist_ok=True)
    log_path = args.data_dir / "serve.log"
    env = {k: v for k, v in os.environ.items() if not k.startswith("NEUENH_")}  # the embedded default
    with open(log_path, "w") as log:  # this run's log only: its first line announces the address
        server = subprocess.Popen([BIN / "neuenh", "serve", "--port", "0", "--data-dir", args.data_dir],
                                  stdout=log, stderr=subprocess.STDOUT, env=env)
    try:
        url = wait_for_service(server, log_path)
        print(f"service   {url}  (log {shown(log_path)})")
        print(f"dashboard {url}/   open it to watch the search live\n", flush=True)
        client = [BIN / "neuenh-client", "--url", url]
        key = "demo-" + (str(time.time_ns()) if args.new else "quickstart")
        submitted = subprocess.run([*client, "submit", args.spec, "--wait", "--idempotency-key", key],
                                   stdout=subprocess.PIPE, text=True, env=env)
        job_id = submitted.stdout.split()[0] if submitted.stdout.split() else None
        if job_id is None:
            return submitted.returncode or 1
        print(f"\njob {job_id}: the path through the hypercube (dashboard: {url}/#job={job_id})")
        subprocess.run([*client, "history", job_id], env=env, check=True)
        results = args.data_dir / "results" / job_id
        results.mkdir(parents=True, exist_ok=True)
        subprocess.run([*client, "download", job_id, "-o", results / "model", "--force"],
                       env=env, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        history = subprocess.run([*client, "history", job_id, "--json"], env=env, check=True,
                                 stdout=subprocess.PIPE, text=True).stdout
        (results / "history.json").write_text(history)
    finally:
        server.send_signal(signal.SIGTERM)
        try:
            server.wait(60)
            print("\nservice stopped (Ray shut down with it)")
        except subprocess.TimeoutExpired:
            server.kill()
            print("\nservice did not stop within 60 s; killed it")
    summarise(json.loads(history), results, args.spec, args.data_dir)
    return submitted.returncode


def wait_for_service(server: subprocess.Popen, log_path: Path, timeout: float = 120.0) -> str:
    """The URL ``neuenh serve`` announces in its log, once ``/v1/health`` answers."""
    deadline, url = time.monotonic() + timeout, None
    while time.monotonic() < deadline:
        if server.poll() is not None:
            sys.exit(f"neuenh serve exited ({server.returncode}):\n{log_path.read_text()[-2000:]}")
        if url is None:
            found = re.search(r"dashboard (http://\S+?)/ ", log_path.read_text())
            url = found.group(1) if found else None
        else:
            try:
                if httpx.get(url + "/v1/health", timeout=5).status_code == 200:
                    return url
            except httpx.HTTPError:
                pass
        time.sleep(0.25)
    sys.exit(f"neuenh serve did not come up within {timeout:.0f} s; see {log_path}")


def summarise(history: dict, results: Path, spec_path: Path, data_dir: Path) -> None:
    """The final state, and its gain over plain GGX trained for the same number of epochs on the
    same data (trained here, after the service stopped, so the comparison is fair)."""
    from neuenh.checkpoint import Bundle
    from neuenh_service.cli.tables import against_plain, still_learning
    from neuenh_service.orchestrator.dataset import prepare_dataset
    from neuenh_service.orchestrator.runner import train_plain_baseline
    from neuenh_service.orchestrator.spec import load_spec
    from neuenh_service.storage import LocalArtifactStore, SQLiteJobStore, trained_epochs

    rounds = history["rounds"]
    if not rounds:
        return
    bundle = Bundle.load(results / "model")
    final = rounds[-1]["winner_val_loss"]
    with SQLiteJobStore(data_dir / "jobs.sqlite") as jobs:  # the service has stopped: read its records
        epochs = trained_epochs(jobs.rounds(history["job_id"]))
    spec = load_spec(spec_path)
    print(f"\nfinal state  {history['current_state']}  {bundle.model.describe()}  ({bundle.model.n_weights()} weights)")
    print(f"val log-L1   {final:.5f} after {epochs} epochs; training plain GGX the same {epochs} epochs ...",
          end=" ", flush=True)
    data, _ = prepare_dataset(spec, LocalArtifactStore(data_dir / "artifacts"))
    baseline = train_plain_baseline(spec, data, epochs)
    print(f"{baseline.val_loss:.5f}\n             -> {against_plain(final, baseline.val_loss, history['current_state'])}")
    caveat = still_learning("plain GGX", baseline.epoch_losses)
    if caveat:
        print(f"                {caveat}")
    print(f"model        {shown(results / 'model')}  (load with neuenh.checkpoint.Bundle.load, "
          f"or: neuenh fit --model {shown(results / 'model')} measurements.npz)")
    print(f"history      {shown(results / 'history.json')}")


def shown(path: Path) -> Path:
    """``path`` relative to the repository when it lies inside it (shorter to read and to paste)."""
    path = path.resolve()
    return path.relative_to(ROOT) if path.is_relative_to(ROOT) else path


if __name__ == "__main__":
    sys.exit(main())
