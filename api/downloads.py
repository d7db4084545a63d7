"""The OpenAPI description of the routes that answer with a file (a model's zip, an export, a plan's
files, the metrics): each media type with a schema, so that a client generated from
``/openapi.json`` keeps those routes and hands the body over as it is — binary files as
``type: string, format: binary`` (openapi-python-client: a ``File``; it reads ``application/zip``
and ``image/png`` as binary once its ``content_type_overrides`` map them to
``application/octet-stream``), text as a string, JSON as a JSON value.
"""

from __future__ import annotations

BINARY = {"type": "string", "format": "binary"}
_TEXT = {"type": "string"}
_JSON = {"type": "object"}


def _schema(media_type: str) -> dict:
    if media_type.startswith("text/"):
        return _TEXT
    return _JSON if media_type == "application/json" else BINARY


def file_response(description: str, *media_types: str) -> dict[int, dict]:
    """OpenAPI ``responses`` for a 200 whose body is a file of one of ``media_types`` (default a zip),
    listed binary ones first: a client that reads one media type per response reads bytes then."""
    ordered = sorted(media_types or ("application/zip",), key=lambda t: _schema(t) is not BINARY)
    return {200: {"description": description, "content": {t: {"schema": _schema(t)} for t in ordered}}}
