"""The service's job queue: queued job ids and the threads that run them, several at once.

(Not to be confused with the ``workers`` room: Ray workers train candidates; these threads drive
whole jobs through the orchestrator, which hands their candidates to the executor.)

At start it queues every unfinished job, then runs jobs as they are submitted: up to
``max_running`` at a time, the highest ``priority`` (of the job's spec) first and in submission
order within a priority. The running jobs divide the cluster through one ``FairShare``. ``stop()``
asks the running jobs to halt at their next safe point *without* cancelling them: each keeps its
status and last committed round, and the next start resumes it (the candidates of the interrupted
round that had finished are read back, the others re-run with the same seeds).
"""

from __future__ import annotations

import heapq
import itertools
import logging
import threading
import time
from typing import Callable

from neuenh_service.orchestrator.executor import Executor
from neuenh_service.orchestrator.runner import Orchestrator, Progress
from neuenh_service.orchestrator.shares import FairShare
from neuenh_service.storage import ArtifactStore, JobRecord, JobStore

log = logging.getLogger("neuenh.api.job_queue")


class _Pending:
    """Queued job ids, highest priority first, first come first within a priority."""

    def __init__(self) -> None:
        self._heap: list[tuple[int, int, str]] = []
        self._order = itertools.count()
        self._ready = threading.Condition()
        self._closed = False

    def put(self, job_id: str, priority: int) -> None:
        with self._ready:
            heapq.heappush(self._heap, (-priority, next(self._order), job_id))
            self._ready.notify()

    def get(self) -> str | None:
        """The next job id; None once closed."""
        with self._ready:
            while not self._heap and not self._closed:
                self._ready.wait()
            return None if self._closed else heapq.heappop(self._heap)[2]

    def close(self) -> None:
        with self._ready:
            self._closed = True
            self._ready.notify_all()

    def __len__(self) -> int:
        with self._ready:
            return len(self._heap)


def priority(job: JobRecord) -> int:
    return int(job.spec.get("priority", 0))


class JobQueue:
    def __init__(self, jobs: JobStore, artifacts: ArtifactStore, executor: Executor,
                 on_progress: Callable[[Progress], None] | None = None, resource_wait_s: float = 600.0,
                 max_running: int = 2):
        if max_running < 1:
            raise ValueError(f"max_running must be at least 1, got {max_running}")
        self._stopping = threading.Event()
        self._pending = _Pending()
        self._progress: dict[str, Progress] = {}
        self._on_progress = on_progress
        self._running: set[str] = set()
        self._running_lock = threading.Lock()
        self.broken: dict[str, str] = {}  # job id -> why it could not be run or updated
        self.jobs = jobs
        self.max_running = max_running
        self.share = FairShare(lambda: _capacity(executor))  # the running jobs' (and plans') shares
        self.orchestrator = Orchestrator(jobs, artifacts, executor, on_progress=self._record,
                                         should_stop=self._stopping.is_set, resource_wait_s=resource_wait_s,
                                         share=self.share)
        self._threads = [threading.Thread(target=self._loop, name=f"neuenh-job-runner-{i}", daemon=True)
                         for i in range(max_running)]

    # -- lifecycle -------------------------------------------------------------------------------
    def start(self) -> list[str]:
        unfinished = self.jobs.unfinished_jobs()
        for job in unfinished:
            self._pending.put(job.id, priority(job))
        resumed = [job.id for job in unfinished]
        if resumed:
            log.info("resuming %d unfinished job(s): %s", len(resumed), ", ".join(resumed))
        for thread in self._threads:
            thread.start()
        return resumed

    def stop(self, timeout: float) -> bool:
        """Ask the threads to stop and wait up to ``timeout`` s in all; True when all stopped."""
        self._stopping.set()
        self._pending.close()
        deadline = time.monotonic() + timeout
        for thread in self._threads:
            thread.join(max(0.0, deadline - time.monotonic()))
        if any(t.is_alive() for t in self._threads):
            log.warning("job(s) %s did not reach a safe stop within %.0f s; they resume on restart",
                        ", ".join(self.running) or "-", timeout)
            return False
        return True

    @property
    def alive(self) -> bool:
        return all(t.is_alive() for t in self._threads)

    # -- work ----------------------------------------------------------------------------------
    def enqueue(self, job: JobRecord) -> None:
        self._pending.put(job.id, priority(job))

    @property
    def queued(self) -> int:
        """Jobs waiting to run (the running ones not included)."""
        return len(self._pending)

    @property
    def running(self) -> list[str]:
        """The jobs running now."""
        with self._running_lock:
            return sorted(self._running)

    def progress(self, job_id: str) -> Progress | None:
        return self._progress.get(job_id)

    def _record(self, p: Progress) -> None:
        self._progress[p.job_id] = p
        if self._on_progress is not None:
            self._on_progress(p)

    def _loop(self) -> None:
        while not self._stopping.is_set():
            job_id = self._pending.get()
            if job_id is None or self._stopping.is_set():
                break
            with self._running_lock:
                if job_id in self._running:  # queued twice (resumed and re-submitted): one runner is enough
                    continue
                self._running.add(job_id)
            try:
                job = self.orchestrator.run(job_id)
                log.info("job %s: %s", job_id, job.status.value)
            except Exception as exc:  # the orchestrator records job failures itself; keep the thread alive
                # ... unless the store itself failed (e.g. a damaged database): the job cannot even
                # be marked FAILED, so it is reported as broken by /health instead of looking RUNNING
                log.exception("job %s: the job queue could not run it", job_id)
                self.broken[job_id] = f"{type(exc).__name__}: {exc}"
            finally:
                with self._running_lock:
                    self._running.discard(job_id)


def _capacity(executor: Executor) -> tuple[float, float]:
    info = executor.cluster()
    return info.cpus, info.gpus
