"""The service's job queue: queued job ids and the one thread that runs them, one at a time.

(Not to be confused with the ``workers`` room: Ray workers train candidates; this thread drives
whole jobs through the orchestrator, which hands their candidates to the executor.)

At start it queues every unfinished job (what ``Orchestrator.resume_all`` would run, oldest
first), then runs jobs as they are submitted. ``stop()`` asks the running job to halt at its next
safe point *without* cancelling it: the job keeps its status and last committed round, and the
next start resumes it (the interrupted round is re-run with the same seeds).
"""

from __future__ import annotations

import logging
import queue
import threading
from typing import Callable

from orchestrator.executor import Executor
from orchestrator.runner import Orchestrator, Progress
from storage import ArtifactStore, JobStore

log = logging.getLogger("neuenh.api.job_queue")

_STOP = object()


class JobQueue:
    def __init__(self, jobs: JobStore, artifacts: ArtifactStore, executor: Executor,
                 on_progress: Callable[[Progress], None] | None = None, resource_wait_s: float = 600.0):
        self._stopping = threading.Event()
        self._queue: queue.Queue = queue.Queue()
        self._progress: dict[str, Progress] = {}
        self._on_progress = on_progress
        self.broken: dict[str, str] = {}  # job id -> why it could not be run or updated
        self.jobs = jobs
        self.orchestrator = Orchestrator(jobs, artifacts, executor, on_progress=self._record,
                                         should_stop=self._stopping.is_set, resource_wait_s=resource_wait_s)
        self.current: str | None = None
        self._thread = threading.Thread(target=self._loop, name="neuenh-job-queue", daemon=True)

    # -- lifecycle -------------------------------------------------------------------------------
    def start(self) -> list[str]:
        resumed = [job.id for job in self.jobs.unfinished_jobs()]
        for job_id in resumed:
            self._queue.put(job_id)
        if resumed:
            log.info("resuming %d unfinished job(s): %s", len(resumed), ", ".join(resumed))
        self._thread.start()
        return resumed

    def stop(self, timeout: float) -> bool:
        """Ask the thread to stop and wait up to ``timeout`` s; True when it has stopped."""
        self._stopping.set()
        self._queue.put(_STOP)
        self._thread.join(timeout)
        if self._thread.is_alive():
            log.warning("job %s did not reach a safe stop within %.0f s; it resumes on restart",
                        self.current, timeout)
            return False
        return True

    @property
    def alive(self) -> bool:
        return self._thread.is_alive()

    # -- work ----------------------------------------------------------------------------------
    def enqueue(self, job_id: str) -> None:
        self._queue.put(job_id)

    @property
    def queued(self) -> int:
        """Jobs waiting to run (the one running not included)."""
        return self._queue.qsize()

    def progress(self, job_id: str) -> Progress | None:
        return self._progress.get(job_id)

    def _record(self, p: Progress) -> None:
        self._progress[p.job_id] = p
        if self._on_progress is not None:
            self._on_progress(p)

    def _loop(self) -> None:
        while not self._stopping.is_set():
            job_id = self._queue.get()
            if job_id is _STOP or self._stopping.is_set():
                break
            self.current = job_id
            try:
                job = self.orchestrator.run(job_id)
                log.info("job %s: %s", job_id, job.status.value)
            except Exception as exc:  # the orchestrator records job failures itself; keep the thread alive
                # ... unless the store itself failed (e.g. a damaged database): the job cannot even
                # be marked FAILED, so it is reported as broken by /health instead of looking RUNNING
                log.exception("job %s: the job queue could not run it", job_id)
                self.broken[job_id] = f"{type(exc).__name__}: {exc}"
            finally:
                self.current = None
