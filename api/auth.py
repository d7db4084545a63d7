"""Who is calling, and what they may do: named tokens with roles.

A studio shares one service. ``NEUENH_TOKENS_FILE`` names a JSON file of tokens, stored hashed::

    [{"name": "alice", "role": "submit", "sha256": "<hex SHA-256 of alice's token>"},
     {"name": "wall",  "role": "read",   "sha256": "..."},
     {"name": "ops",   "role": "admin",  "sha256": "..."}]

(``printf %s "$TOKEN" | sha256sum`` gives a token's hash). Roles:

* ``admin`` — every route, every job;
* ``submit`` — submits jobs; sees, follows, fits with and cancels **its own** jobs (others' are
  404, as if absent); reads the cluster and the service's health;
* ``read`` — dashboards and polling: every ``GET`` of every job, nothing that changes anything.

``NEUENH_API_TOKEN`` keeps working as one more token, an admin named ``admin``. With neither, the
service is loopback-only and every caller is the local admin. The file is read at start and again
on SIGHUP (``neuenh serve``); a file that does not parse keeps the previous tokens and logs why.
Each job records the name of the token that submitted it (its owner).
"""

from __future__ import annotations

import enum
import hashlib
import hmac
import json
import logging
import threading
from dataclasses import dataclass
from pathlib import Path

from fastapi import HTTPException, status

from .settings import Settings

log = logging.getLogger("neuenh.api")


class Role(str, enum.Enum):
    ADMIN = "admin"
    SUBMIT = "submit"
    READ = "read"


@dataclass(frozen=True)
class Principal:
    """The caller: a token's name and role (``local``, admin, when the service has no tokens)."""

    name: str
    role: Role

    @property
    def sees_all(self) -> bool:
        return self.role in (Role.ADMIN, Role.READ)

    def may_see(self, owner: str | None) -> bool:
        return self.sees_all or owner == self.name

    def may_change(self, owner: str | None) -> bool:
        return self.role is Role.ADMIN or (self.role is Role.SUBMIT and owner == self.name)


LOCAL = Principal("local", Role.ADMIN)


def token_hash(token: str) -> str:
    return hashlib.sha256(token.encode()).hexdigest()


class TokenTable:
    """The named tokens, by hash; ``reload`` re-reads the file (thread-safe swap)."""

    def __init__(self, settings: Settings):
        self.settings = settings
        self._by_hash: dict[str, Principal] = {}
        self._lock = threading.Lock()
        self.reload(strict=True)

    @property
    def configured(self) -> bool:
        return bool(self._by_hash)

    def reload(self, strict: bool = False) -> None:
        """Read the tokens again. ``strict`` (at start): a bad file is a ``ValueError`` naming
        what is wrong; later (SIGHUP) it is logged and the current tokens stay."""
        try:
            table = _read(self.settings.tokens_file) if self.settings.tokens_file else {}
        except ValueError as exc:
            if strict:
                raise
            log.error("keeping the current tokens: %s", exc)
            return
        if self.settings.api_token is not None:
            table[token_hash(self.settings.api_token.get_secret_value())] = Principal("admin", Role.ADMIN)
        with self._lock:
            self._by_hash = table
        if self.settings.tokens_file:
            log.info("tokens: %d named token(s) from %s", len(table), self.settings.tokens_file)

    def authenticate(self, authorization: str | None) -> Principal:
        """The caller of a request with this ``Authorization`` header value, or a 401."""
        with self._lock:
            table = self._by_hash
        if not table:
            return LOCAL
        scheme, _, token = (authorization or "").partition(" ")
        if scheme.lower() != "bearer" or not token.strip():
            raise HTTPException(status.HTTP_401_UNAUTHORIZED, "missing bearer token (Authorization: Bearer <token>)",
                                headers={"WWW-Authenticate": "Bearer"})
        digest = token_hash(token.strip())
        for known, principal in table.items():  # constant time per entry: no early exit on a prefix
            if hmac.compare_digest(known, digest):
                return principal
        raise HTTPException(status.HTTP_401_UNAUTHORIZED, "invalid bearer token",
                            headers={"WWW-Authenticate": 'Bearer error="invalid_token"'})


def _read(path: Path) -> dict[str, Principal]:
    try:
        entries = json.loads(Path(path).read_text())
    except OSError as exc:
        raise ValueError(f"NEUENH_TOKENS_FILE {path}: cannot be read ({exc.strerror or exc})") from None
    except json.JSONDecodeError as exc:
        raise ValueError(f"NEUENH_TOKENS_FILE {path}: not JSON ({exc})") from None
    if not isinstance(entries, list):
        raise ValueError(f"NEUENH_TOKENS_FILE {path}: a JSON list of {{name, role, sha256}} objects")
    table: dict[str, Principal] = {}
    names: set[str] = set()
    for i, entry in enumerate(entries):
        where = f"NEUENH_TOKENS_FILE {path}: entry {i}"
        if not isinstance(entry, dict) or set(entry) != {"name", "role", "sha256"}:
            raise ValueError(f"{where}: needs exactly the keys name, role, sha256")
        name, role, digest = entry["name"], entry["role"], entry["sha256"]
        if not isinstance(name, str) or not name or name in names:
            raise ValueError(f"{where}: name must be a non-empty string, unique in the file")
        if role not in {r.value for r in Role}:
            raise ValueError(f"{where}: role {role!r} is not one of admin, submit, read")
        if not isinstance(digest, str) or len(digest) != 64 or any(c not in "0123456789abcdef" for c in digest):
            raise ValueError(f"{where}: sha256 must be the 64 lowercase hex digits of the token's SHA-256")
        names.add(name)
        table[digest] = Principal(name, Role(role))
    return table
