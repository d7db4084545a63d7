"""Fair shares of the cluster: max-min fairness against hand-worked splits, and what a job may
have in flight as others start and end."""

import pytest

from neuenh_service.orchestrator.executor import Resources
from neuenh_service.orchestrator.shares import FairShare, water_fill

ONE_CPU, TWO_CPUS, ONE_GPU = Resources(1.0), Resources(2.0), Resources(1.0, 1.0)


@pytest.mark.parametrize("capacity,demands,expected", [
    (12, {"a": 12}, {"a": 12}),                                  # alone: all it wants
    (12, {"a": 12, "b": 12}, {"a": 6, "b": 6}),                  # equal split
    (12, {"a": 2, "b": 12, "c": 12}, {"a": 2, "b": 5, "c": 5}),  # a's unused share goes to the others
    (10, {"a": 1, "b": 2, "c": 30}, {"a": 1, "b": 2, "c": 7}),
    (2, {"a": 12, "b": 12, "c": 12}, {"a": 2 / 3, "b": 2 / 3, "c": 2 / 3}),
    (64, {"a": 3, "b": 4}, {"a": 3, "b": 4}),                   # room for everyone
    (0, {"a": 5}, {"a": 0}),
])
def test_water_fill_is_max_min_fair(capacity, demands, expected):
    shares = water_fill(capacity, demands)
    assert shares == pytest.approx(expected)
    assert sum(shares.values()) <= capacity + 1e-9
    assert all(shares[j] <= demands[j] + 1e-9 for j in demands)


def test_limits_rebalance_as_jobs_start_and_end():
    share = FairShare(lambda: (12.0, 0.0), refresh_s=0.0)
    assert share.limit("a", ONE_CPU, 12) == 12          # alone: the whole cluster
    assert share.limit("b", ONE_CPU, 12) == 6           # b starts: half each
    assert share.limit("a", ONE_CPU, 12) == 6
    assert share.limit("c", TWO_CPUS, 12) == 2          # c's candidates take 2 CPUs: 4 CPUs = 2 of them
    assert share.limit("a", ONE_CPU, 3) == 3            # a wants less than its share ...
    assert share.limit("b", ONE_CPU, 12) == 4           # ... so b and c split the rest: 9 / 2 = 4.5 CPUs each
    assert share.limit("c", TWO_CPUS, 12) == 2
    share.leave("a"), share.leave("c")
    assert share.limit("b", ONE_CPU, 12) == 12          # the others ended: b has it all


def test_every_job_may_run_one_candidate_however_many_share():
    share = FairShare(lambda: (2.0, 0.0), refresh_s=0.0)
    assert [share.limit(j, ONE_CPU, 12) for j in "abcde"] == [2, 1, 1, 1, 1]
    assert share.limit("a", ONE_CPU, 0) == 0  # wants nothing: holds nothing


def test_gpu_jobs_share_the_gpus_and_cpu_only_jobs_are_not_counted_there():
    share = FairShare(lambda: (16.0, 2.0), refresh_s=0.0)
    assert share.limit("cpu-only", ONE_CPU, 12) == 12
    assert share.limit("g1", ONE_GPU, 8) == 2   # the GPUs bind, not its 8 CPUs (half of 16)
    assert share.limit("g2", ONE_GPU, 8) == 1   # 2 GPUs between two GPU jobs
    assert share.limit("g1", ONE_GPU, 8) == 1
    share.leave("g2")
    assert share.limit("g1", ONE_GPU, 8) == 2


def test_the_cluster_is_read_at_most_every_refresh():
    calls = []

    def capacity():
        calls.append(1)
        return (4.0, 0.0)

    share = FairShare(capacity, refresh_s=3600)
    for _ in range(20):
        share.limit("a", ONE_CPU, 4)
    assert len(calls) == 1
