"""``/metrics``: the service in Prometheus' text format, through ``prometheus-client``.

One ``CollectorRegistry`` per app (built in the lifespan, never the process-global one). Counts and
durations come from the job store at scrape time, so they are durable: a restart does not reset
them (Prometheus' ``rate()`` sees no counter reset). The queue and the cluster come from the job
queue and the executor; fits served are counted in-process (reset by a restart, as counters may).

    neuenh_jobs{status}                    gauge      jobs in each status
    neuenh_candidates_total{result}        counter    committed candidates, result="ok"|"failed"
    neuenh_candidate_seconds               histogram  a candidate's training wall time
    neuenh_round_seconds                   histogram  a round's wall time
    neuenh_queue_length                    gauge      jobs waiting to run
    neuenh_cluster_slots_busy              gauge      candidates submitted and not yet reported
    neuenh_cluster_cpus{state}             gauge      CPUs of the cluster, state="total"|"available"
    neuenh_fits_total                      counter    fits served by POST /v1/jobs/{id}/fit
"""

from __future__ import annotations

import bisect
from typing import Iterable, Iterator

from prometheus_client import CollectorRegistry, Counter, generate_latest
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, HistogramMetricFamily, Metric
from prometheus_client.registry import Collector

from neuenh_service.storage import JobStatus, JobStore

# Seconds: candidates train from seconds (tests) to hours (the paper's scale).
BUCKETS = (1, 5, 15, 60, 300, 900, 3600, 4 * 3600)


class ServiceMetrics:
    def __init__(self, jobs: JobStore, job_queue, executor):
        self.registry = CollectorRegistry()
        self.fits = Counter("neuenh_fits", "fits served by POST /v1/jobs/{id}/fit", registry=self.registry)
        self.registry.register(_ServiceCollector(jobs, job_queue, executor))

    def render(self) -> bytes:
        return generate_latest(self.registry)


class _ServiceCollector(Collector):
    def __init__(self, jobs: JobStore, job_queue, executor):
        self.jobs, self.job_queue, self.executor = jobs, job_queue, executor

    def collect(self) -> Iterator[Metric]:
        stats = self.jobs.statistics()
        jobs = GaugeMetricFamily("neuenh_jobs", "jobs in each status", labels=["status"])
        for status in JobStatus:
            jobs.add_metric([status.value], stats.jobs_by_status.get(status, 0))
        yield jobs
        candidates = CounterMetricFamily("neuenh_candidates", "committed candidates", labels=["result"])
        candidates.add_metric(["ok"], stats.candidates - stats.failed_candidates)
        candidates.add_metric(["failed"], stats.failed_candidates)
        yield candidates
        yield _histogram("neuenh_candidate_seconds", "a candidate's training wall time", stats.candidate_seconds)
        yield _histogram("neuenh_round_seconds", "a round's wall time", stats.round_seconds)
        yield GaugeMetricFamily("neuenh_queue_length", "jobs waiting to run", value=self.job_queue.queued)
        cluster = self.executor.cluster()
        yield GaugeMetricFamily("neuenh_cluster_slots_busy", "candidates submitted and not yet reported",
                                value=cluster.busy_candidates)
        cpus = GaugeMetricFamily("neuenh_cluster_cpus", "CPUs of the cluster", labels=["state"])
        cpus.add_metric(["total"], cluster.cpus)
        cpus.add_metric(["available"], cluster.cpus_available)
        yield cpus


def _histogram(name: str, documentation: str, values: Iterable[float]) -> HistogramMetricFamily:
    values = sorted(values)
    buckets = [(str(float(b)), bisect.bisect_right(values, b)) for b in BUCKETS] + [("+Inf", len(values))]
    return HistogramMetricFamily(name, documentation, buckets=buckets, sum_value=sum(values))
