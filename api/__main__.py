"""``python -m neuenh_service.api``: the service with settings from the environment (``neuenh serve`` adds flags)."""

from .server import serve
from .settings import Settings

if __name__ == "__main__":
    serve(Settings())
