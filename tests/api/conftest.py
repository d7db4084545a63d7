from live_api import live_server  # noqa: F401  (fixture)
