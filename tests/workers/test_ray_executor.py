"""The Ray executor on an embedded local Ray: same results as in-process, failures as reports,
cancellation, and a whole job."""

import threading
import time

import pytest
import ray
import torch

from neuenh.checkpoint import Bundle
from neuenh.data.sources import SyntheticZoo, materialise
from neuenh.train import TrainConfig
from neuenh_service.orchestrator.executor import CandidateTask, TrainRequest
from neuenh_service.orchestrator.runner import Orchestrator
from jobspecs import tiny_spec
from neuenh_service.storage import JobStatus, LocalArtifactStore, SQLiteJobStore
from neuenh_service.workers.inline import InlineExecutor
from neuenh_service.workers.ray_executor import RayExecutor
from ggx_states import PAPER_STATE

CONFIG = TrainConfig(epochs=1, batch_size=1000, lr=5e-3)


@pytest.fixture(scope="module")
def executor():
    if ray.is_initialized():
        ray.shutdown()
    ex = RayExecutor(num_cpus=2, object_store_memory=100 * 1024**2)
    yield ex
    ex.close()


@pytest.fixture(scope="module")
def data():
    return materialise([SyntheticZoo(source="synthetic_zoo", materials=2, samples=300, seed=1)], 0.1, 0)


def _tasks(*states, epochs=1):
    return [CandidateTask(s, seed=i, epochs=epochs) for i, s in enumerate(states)]


def test_ray_matches_in_process_training(executor, data):
    parent = Bundle.initial("ggx", data.names).to_bytes()
    tasks = _tasks("00000000000", "00010000000", "00000100000")
    remote = {r.task.state: r for r in executor.train(TrainRequest(executor.put_dataset(data), [parent], tasks, CONFIG))}
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # the Ray tasks ran with one thread each (cpus_per_candidate = 1)
    local = {r.task.state: r for r in InlineExecutor().train(TrainRequest(data, [parent], tasks, CONFIG))}
    torch.set_num_threads(threads)
    assert set(remote) == set(local)
    node_ids = {n["NodeID"] for n in ray.nodes()}
    for state, r in remote.items():
        assert r.ok and r.node in node_ids
        assert (r.train_loss, r.val_loss) == (local[state].train_loss, local[state].val_loss)


def test_a_failing_candidate_comes_back_as_a_report(executor, data):
    parent = Bundle.initial("ggx", data.names).to_bytes()
    reports = list(executor.train(TrainRequest(executor.put_dataset(data), [parent],
                                               _tasks("00000000000", "99999999999"), CONFIG)))
    by_state = {r.task.state: r for r in reports}
    assert by_state["00000000000"].ok
    bad = by_state["99999999999"]
    assert not bad.ok and bad.bundle is None and bad.error.startswith("ValueError") and "digit '9'" in bad.error


def test_cancellation_stops_the_remaining_candidates(executor, data):
    parent = Bundle.initial("ggx", data.names).to_bytes()
    flag = threading.Event()
    tasks = _tasks(*([PAPER_STATE] * 1 + [f"{'0' * i}1{'0' * (10 - i)}" for i in range(11)]), epochs=30)
    got = []
    for report in executor.train(TrainRequest(executor.put_dataset(data), [parent], tasks, CONFIG), cancelled=flag.is_set):
        got.append(report)
        flag.set()
    assert 1 <= len(got) < len(tasks)


def test_a_job_on_ray_takes_the_same_path_as_in_process(executor, tmp_path):
    def run(ex, where):
        jobs = SQLiteJobStore(tmp_path / f"{where}.sqlite")
        o = Orchestrator(jobs, LocalArtifactStore(tmp_path / where), ex)
        job = o.run(o.submit(tiny_spec(max_rounds=2))[0].id)
        path = [(r.winner_state, r.winner_val_loss, sorted((c.state, c.val_loss) for c in r.candidates))
                for r in jobs.rounds(job.id)]
        nodes = {c.node for r in jobs.rounds(job.id) for c in r.candidates}
        return job, path, nodes

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    _, local_path, _ = run(InlineExecutor(), "inline")
    torch.set_num_threads(threads)
    job, ray_path, nodes = run(executor, "ray")
    assert job.status in (JobStatus.CONVERGED, JobStatus.STOPPED)
    assert ray_path == local_path
    assert nodes <= {n["NodeID"] for n in ray.nodes()}


def test_cancelling_a_job_mid_round_on_ray(executor, tmp_path):
    jobs = SQLiteJobStore(tmp_path / "jobs.sqlite")
    orchestrator = Orchestrator(jobs, LocalArtifactStore(tmp_path / "a"), executor)
    job, _ = orchestrator.submit(tiny_spec(max_rounds=5, epochs_per_round=20))

    def cancel_when_round_1_runs():
        while True:
            events = jobs.events(job.id)
            if any(e.kind == "candidate" and e.payload["round"] == 1 for e in events):
                jobs.set_status(job.id, JobStatus.CANCELLED)  # what POST /jobs/{id}/cancel does
                return
            threading.Event().wait(0.02)

    canceller = threading.Thread(target=cancel_when_round_1_runs)
    canceller.start()
    final = orchestrator.run(job.id)
    canceller.join()
    assert final.status == JobStatus.CANCELLED
    assert [r.index for r in jobs.rounds(job.id)] == [0]
    # The cancelled candidates no longer hold the cluster's CPUs.
    deadline = time.time() + 20
    while ray.available_resources().get("CPU", 0) < ray.cluster_resources()["CPU"] and time.time() < deadline:
        time.sleep(0.1)
    assert ray.available_resources().get("CPU", 0) == ray.cluster_resources()["CPU"]
