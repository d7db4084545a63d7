"""One router per resource: ``jobs`` (submit, list, status, history, cancel, model) and ``health``."""
