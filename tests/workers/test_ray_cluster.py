"""Two Ray nodes on one machine (ray.cluster_utils.Cluster: a head without CPUs for tasks and two
worker nodes, each its own raylet): candidates run on both, and a node removed mid-round does not
stop the round."""

import pytest
import ray
from ray.cluster_utils import Cluster

from neuenh.checkpoint import Bundle
from neuenh.data.sources import SyntheticZoo, materialise
from neuenh.train import TrainConfig
from neuenh_service.orchestrator.executor import CandidateTask, TrainRequest
from neuenh_service.workers.ray_executor import RayExecutor

STATES = [f"{'0' * i}1{'0' * (10 - i)}" for i in range(11)] + ["0" * 11]
CONFIG = TrainConfig(epochs=2, batch_size=1000, lr=5e-3)


@pytest.fixture(scope="module")
def cluster():
    """One cluster for the module's two tests, in file order: the second removes a node. Ray's workers
    (torch imported) serve both, instead of two clusters each starting its own."""
    if ray.is_initialized():
        ray.shutdown()
    c = Cluster(initialize_head=True, head_node_args={"num_cpus": 0})
    workers = [c.add_node(num_cpus=1), c.add_node(num_cpus=1)]
    c.wait_for_nodes()
    ray.init(address=c.address, log_to_driver=False)
    yield c, workers
    ray.shutdown()
    c.shutdown()


@pytest.fixture(scope="module")
def job_inputs():
    data = materialise([SyntheticZoo(source="synthetic_zoo", materials=2, samples=600, seed=1)], 0.1, 0)
    return data, Bundle.initial("ggx", data.names).to_bytes()


def test_candidates_run_on_both_worker_nodes(cluster, job_inputs):
    c, workers = cluster
    data, parent = job_inputs
    executor = RayExecutor(address=c.address)
    reports = list(executor.train(TrainRequest(executor.put_dataset(data), [parent],
                                               [CandidateTask(s, seed=1, epochs=2) for s in STATES], CONFIG)))
    assert len(reports) == 12 and all(r.ok for r in reports)
    assert {r.node for r in reports} == {w.node_id for w in workers}


def test_a_node_removed_mid_round_still_completes_the_round(cluster, job_inputs):
    c, workers = cluster
    data, parent = job_inputs
    executor = RayExecutor(address=c.address, max_retries=3)
    reports = []
    for report in executor.train(TrainRequest(executor.put_dataset(data), [parent],
                                              [CandidateTask(s, seed=1, epochs=4) for s in STATES], CONFIG)):
        reports.append(report)
        if len(reports) == 2:
            c.remove_node(workers[1])  # its running candidate dies with it and is retried
    assert sorted(r.task.state for r in reports) == sorted(STATES)
    assert all(r.ok for r in reports), [r.error for r in reports if not r.ok]
    # After the removal only the surviving node trains (one report of the removed node may have
    # finished just before it went away).
    assert sum(r.node == workers[1].node_id for r in reports[2:]) <= 1
    assert sum(r.node == workers[0].node_id for r in reports[2:]) >= len(reports) - 3


def test_without_an_address_the_executor_starts_its_own_ray_beside_a_ray_start_cluster():
    """A cluster started with ``ray start`` (Cluster writes /tmp/ray/ray_current_cluster as it does)
    is not joined by an executor given no address: embedded Ray means a Ray of its own, with the
    CPUs it was asked for, not an error about options an existing cluster refuses."""
    if ray.is_initialized():
        ray.shutdown()
    other = Cluster(initialize_head=True, head_node_args={"num_cpus": 1})
    try:
        executor = RayExecutor(num_cpus=2)
        try:
            assert ray.get_runtime_context().gcs_address != other.address
            assert ray.cluster_resources()["CPU"] == 2
        finally:
            executor.close()
    finally:
        other.shutdown()
