"""The REST service (ARCHITECTURE §3-4): FastAPI app, routes under ``/v1``, schemas, dependencies, and
the dashboard page at ``/`` (``api/dashboard/``).

Nothing is built at import time: ``create_app(settings)`` returns an app whose lifespan builds the
job store, artifact store, executor, orchestrator and the background job worker, and closes them
on shutdown. Run it with ``neuenh serve`` (``api.server.serve``: settings from flags and the
environment, checks before starting) or ``python -m neuenh_service.api``.
"""
