"""``python -m api``: serve the API with uvicorn on ``NEUENH_HOST``:``NEUENH_PORT``."""

from __future__ import annotations

import logging


def serve(settings=None) -> None:
    import uvicorn

    from .app import create_app
    from .settings import Settings, check_listen_address

    settings = settings or Settings()
    check_listen_address(settings)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    uvicorn.run(create_app(settings), host=settings.host, port=settings.port,
                limit_concurrency=64, timeout_graceful_shutdown=10)


if __name__ == "__main__":
    serve()
