"""Executors that train candidate states: Ray (the real one) and inline (tests only)."""
