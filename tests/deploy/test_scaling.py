"""Scaling with the radius: while a round runs, the Ray executor asks the cluster (its autoscaler,
through ``request_resources``) for one bundle per candidate of the shape each candidate takes, so a
larger radius asks for more workers; the request is withdrawn when the round ends. Read back from
the cluster's GCS, where an autoscaler (``ray up``, KubeRay) reads it."""

from __future__ import annotations

import json

import pytest
import ray

from neuenh.checkpoint import Bundle
from neuenh.data.sources import SyntheticZoo, materialise
from neuenh.search import hamming_ball
from neuenh.train import TrainConfig
from neuenh_service.orchestrator.executor import CandidateTask, Resources, TrainRequest
from neuenh_service.workers.ray_executor import RayExecutor


def requested_bundles() -> list[dict]:
    """The standing resource request of this cluster, as the autoscaler sees it."""
    from ray.autoscaler.v2.utils import is_autoscaler_v2

    if is_autoscaler_v2():
        from ray.autoscaler.v2.sdk import get_cluster_resource_state

        state = get_cluster_resource_state(ray._private.worker.global_worker.gcs_client)
        return [dict(b.resources_bundle) for c in state.cluster_resource_constraints
                for r in c.resource_requests for b in [r.request] for _ in range(r.count)]
    from ray._private.ray_constants import AUTOSCALER_RESOURCE_REQUEST_CHANNEL
    from ray.experimental.internal_kv import _internal_kv_get

    raw = _internal_kv_get(AUTOSCALER_RESOURCE_REQUEST_CHANNEL)
    return json.loads(raw) if raw else []


@pytest.fixture(scope="module")
def executor():
    if ray.is_initialized():
        ray.shutdown()
    ex = RayExecutor(num_cpus=1, object_store_memory=100 * 1024**2)
    yield ex
    ex.close()


@pytest.mark.parametrize("radius, n", [(1, 12), (2, 67)])
def test_a_round_asks_the_cluster_for_one_bundle_per_candidate(executor, radius, n):
    data = materialise([SyntheticZoo(source="synthetic_zoo", materials=1, samples=100, seed=1)], 0.1, 0)
    parent = Bundle.initial("ggx", data.names).to_bytes()
    states = ["".join(map(str, s)) for s in hamming_ball((0,) * 11, radius, 2)]
    assert len(states) == n  # GGX: 1 + 11 (+ 55)
    tasks = [CandidateTask(s, seed=1, epochs=1) for s in states]
    rounds = executor.train(TrainRequest(executor.put_dataset(data), [parent], tasks,
                                         TrainConfig(epochs=1, batch_size=1000), Resources(cpus=0.5)))
    next(rounds)  # the round is under way
    during = requested_bundles()
    rounds.close()  # the caller stops the round (e.g. a cancel): the request is withdrawn too
    assert during == [{"CPU": 0.5}] * n
    assert requested_bundles() == []
