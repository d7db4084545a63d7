"""One scene plan in a process of its own (``PlanQueue`` starts it): a runaway plan — a fit of a
billion epochs, a material that swells memory — costs that process, which a cancel or a stop ends at
once, never the API's threads, its memory or its shutdown.

The process opens its own plan store (the service's SQLite file) and artifact store from the
service's settings, runs ``orchestrator.plans.PlanRunner`` on one plan, and sends each progress step
(``message, step, steps``) through the pipe it was given. It runs with ``settings.plan_cpus``
torch threads, at a lower scheduling priority than the API (``nice`` +10), and dies with the
process that started it (Linux ``PR_SET_PDEATHSIG``), so a killed service leaves no planner behind.
"""

from __future__ import annotations

import logging
import os
from multiprocessing.connection import Connection
from pathlib import Path

from neuenh.allocator import keep_freed_memory
from neuenh.processes import die_with_parent

from .settings import Settings

NICENESS = 10  # the API's event loop and the job threads go first when the CPUs are busy


def run_plan(settings: Settings, base: Path, plan_id: str, progress: Connection) -> None:
    """The process's entry point (``multiprocessing``): plan ``plan_id`` to its end (DONE, FAILED)."""
    die_with_parent()
    os.nice(NICENESS)

    from neuenh.fit.jit import set_fit_threads
    from neuenh_service.orchestrator.plans import PlanRunner
    from neuenh_service.storage import SQLitePlanStore

    from .stores import artifact_store

    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    set_fit_threads(settings.plan_cpus)  # no Mitsuba runs here (it needs more than one Dr.Jit thread)
    keep_freed_memory()  # a plan's fits reuse their freed activations (neuenh.allocator)
    plans, artifacts = SQLitePlanStore(settings.data_dir / "jobs.sqlite"), artifact_store(settings)
    try:
        PlanRunner(plans, artifacts, base=base, max_materials=settings.max_materials,
                   on_progress=lambda _, message, step, steps: progress.send((message, step, steps))).run(plan_id)
    finally:
        progress.close()
        plans.close()
        artifacts.close()
