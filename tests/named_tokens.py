"""Named tokens with roles for API tests (``NEUENH_TOKENS_FILE``): an admin, two submitters, a reader."""

from __future__ import annotations

import hashlib
import json

TOKENS = {"ops": ("admin", "t-ops"), "alice": ("submit", "t-alice"), "bob": ("submit", "t-bob"),
          "wall": ("read", "t-wall")}


def write_tokens(path, tokens=TOKENS):
    """The tokens file (their SHA-256 only); returns ``path``."""
    path.write_text(json.dumps([{"name": name, "role": role, "sha256": hashlib.sha256(token.encode()).hexdigest()}
                                for name, (role, token) in tokens.items()]))
    return path


def as_(name: str) -> dict:
    """The Authorization header of ``name``'s token."""
    return {"Authorization": f"Bearer {TOKENS[name][1]}"}
