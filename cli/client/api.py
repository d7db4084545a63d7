"""The neuenh service as ``neuenh-client`` sees it: one ``Api`` over httpx whose every failure is a
``ClientError`` carrying a one-line reason and the exit code of ARCHITECTURE §4.

=============================================  ====  ==========================================
what happened                                  exit  the line says
=============================================  ====  ==========================================
connection refused, unknown host, timeout       3    cannot reach URL (reason); how to fix it
401 (no token, or the wrong one)                3    URL refused the token (detail); the fix
429 (one fit or upload at a time: busy)         3    the service is busy (detail); retry in N s
any other 4xx (404 no such job, 409, 422 ...)   2    the service's ``detail``
507 (a stored artifact is damaged)              1    what is damaged (detail); the operator restores it
other 5xx                                       1    the service failed (status: detail)
=============================================  ====  ==========================================

The token travels only in the ``Authorization`` header and is never part of a message.
"""

from __future__ import annotations

import json
import re
from typing import Any

import httpx

DEFAULT_URL = "http://127.0.0.1:8000"
CONNECT_TIMEOUT_S = 5.0
READ_TIMEOUT_S = 30.0  # an answer's default wait (``--timeout``); the long calls below wait longer
DOWNLOAD_TIMEOUT_S = 300.0  # a model, an export, a scene's uploaded files
FIT_TIMEOUT_S = 3600.0  # fitting materials on the service

OK, JOB_FAILED, USAGE, UNREACHABLE = 0, 1, 2, 3
DAMAGED_ARTIFACT = 507  # the service's answer for a stored artifact whose bytes changed since written


class ClientError(Exception):
    """A failure reported in one line; ``code`` is the exit code, ``status`` the HTTP status if any."""

    def __init__(self, message: str, code: int, status: int | None = None):
        super().__init__(message)
        self.code, self.status = code, status


def service_url(url: str) -> str:
    """``url`` as the service's root: a scheme added when missing, no trailing ``/`` or ``/v1``."""
    url = url.strip()
    if "://" not in url:
        url = "http://" + url
    url = url.rstrip("/")
    return url[: -len("/v1")] if url.endswith("/v1") else url


class Api:
    """Calls to ``URL/v1``: each returns the decoded JSON (or the response) or raises ClientError."""

    def __init__(self, url: str, token: str | None, *, read_timeout: float = READ_TIMEOUT_S):
        from neuenh import __version__

        self.url = service_url(url)
        self.token_sent = bool(token)
        headers = {"User-Agent": f"neuenh-client/{__version__}"}
        if token:
            headers["Authorization"] = f"Bearer {token}"
        self.read_timeout = read_timeout
        try:
            self.http = httpx.Client(base_url=self.url + "/v1", headers=headers,
                                     timeout=httpx.Timeout(read_timeout, connect=CONNECT_TIMEOUT_S))
        except (httpx.InvalidURL, ValueError) as exc:
            raise ClientError(f"--url {url!r} is not a usable URL ({exc})", USAGE) from None

    def close(self) -> None:
        self.http.close()

    # -- the calls ---------------------------------------------------------------------------
    def health(self) -> dict:
        return self.call("GET", "/health")

    def job(self, job_id: str) -> dict:
        return self.call("GET", f"/jobs/{job_id}")

    def history(self, job_id: str, since_round: int = 0) -> dict:
        return self.call("GET", f"/jobs/{job_id}/history", params={"since_round": since_round})

    def jobs(self, status: list[str] | None = None, limit: int = 20) -> list[dict]:
        """The newest ``limit`` jobs (following the pages), optionally of the given statuses."""
        found: list[dict] = []
        cursor = None
        while len(found) < limit:
            params: dict[str, Any] = {"limit": min(limit - len(found), 500)}
            if status:
                params["status"] = status
            if cursor:
                params["cursor"] = cursor
            page = self.call("GET", "/jobs", params=params)
            found += page["jobs"]
            cursor = page["next_cursor"]
            if not cursor:
                break
        return found

    def submit(self, spec: dict, idempotency_key: str | None = None) -> tuple[dict, bool]:
        """The job, and whether the service created it (False: the key's earlier job)."""
        return self._create("/jobs", idempotency_key, json=spec)

    def _create(self, path: str, idempotency_key: str | None, **body) -> tuple[dict, bool]:
        """POST ``body`` (``json=`` or ``data=``/``files=``): the created or found resource, and
        whether the service created it (202) rather than found it under the key (200)."""
        headers = {"Idempotency-Key": idempotency_key} if idempotency_key else {}
        r = self.request("POST", path, headers=headers, **body)
        return self._json(r), r.status_code == 202

    def cancel(self, job_id: str) -> dict:
        return self.call("POST", f"/jobs/{job_id}/cancel")

    def cancel_plan(self, plan_id: str) -> dict:
        return self.call("POST", f"/plans/{plan_id}/cancel")

    def model(self, job_id: str, read_timeout: float) -> httpx.Response:
        return self.request("GET", f"/jobs/{job_id}/model", read_timeout=read_timeout)

    def fit(self, job_id: str, files: list, data: dict, read_timeout: float) -> dict:
        return self.call("POST", f"/jobs/{job_id}/fit", files=files, data=data, read_timeout=read_timeout)

    def export(self, job_id: str, fmt: str, materials: list[str] | None, read_timeout: float) -> bytes:
        params = [("format", fmt), *(("material", m) for m in materials or ())]
        return self.request("GET", f"/jobs/{job_id}/export", params=params, read_timeout=read_timeout).content

    def submit_plan(self, scene: dict, idempotency_key: str | None = None) -> tuple[dict, bool]:
        """The plan, and whether the service created it."""
        return self._create("/plans", idempotency_key, json=scene)

    def submit_plan_with_files(self, scene: dict, files: list, idempotency_key: str | None = None,
                               read_timeout: float | None = None) -> tuple[dict, bool]:
        """The plan of ``scene`` planned from the measured ``files`` sent with it (multipart
        ``(name, handle)`` pairs), and whether the service created it."""
        return self._create("/plan-uploads", idempotency_key, data={"scene": json.dumps(scene)},
                            files=[("files", f) for f in files], read_timeout=read_timeout)

    def plan(self, plan_id: str) -> dict:
        return self.call("GET", f"/plans/{plan_id}")

    def plan_file(self, plan_id: str, name: str) -> bytes:
        return self.request("GET", f"/plans/{plan_id}/files/{name}").content

    def cluster(self) -> dict | None:
        """``GET /v1/cluster``, or None from a service that does not have it."""
        try:
            return self.call("GET", "/cluster")
        except ClientError as exc:
            if exc.status == 404:
                return None
            raise

    # -- transport and errors ----------------------------------------------------------------
    def call(self, method: str, path: str, **kw) -> Any:
        """``request`` and its JSON."""
        return self._json(self.request(method, path, **kw))

    def _json(self, r: httpx.Response) -> Any:
        try:
            return r.json()
        except ValueError:
            raise ClientError(f"{self.url} answered {r.request.method} {r.request.url.path} with something "
                              "other than JSON; is it a neuenh service? set --url or NEUENH_URL",
                              UNREACHABLE) from None

    def request(self, method: str, path: str, *, read_timeout: float | None = None, **kw) -> httpx.Response:
        if read_timeout is not None:
            kw["timeout"] = httpx.Timeout(read_timeout, connect=CONNECT_TIMEOUT_S)
        try:
            r = self.http.request(method, path, **kw)
        except httpx.ConnectTimeout:
            raise self._unreachable(f"no connection within {CONNECT_TIMEOUT_S:g} s") from None
        except httpx.TimeoutException:
            raise ClientError(f"{self.url} did not answer within {read_timeout or self.read_timeout:g} s "
                              "(raise --timeout if the service is busy)", UNREACHABLE) from None
        except httpx.UnsupportedProtocol as exc:
            raise ClientError(f"--url {self.url!r} is not a usable URL ({exc})", USAGE) from None
        except httpx.TransportError as exc:
            raise self._unreachable(_reason(exc)) from None
        if r.is_success:
            return r
        detail = _detail(r)
        if r.status_code == 401:
            what = "refused the token" if self.token_sent else "requires a token"
            raise ClientError(f"{self.url} {what} ({detail}); set --token or NEUENH_API_TOKEN",
                              UNREACHABLE, r.status_code)
        if r.status_code == 429:  # busy now, fine later: like an unreachable service, worth a retry
            retry = r.headers.get("Retry-After")
            raise ClientError(f"{self.url} is busy ({detail})" + (f"; retry in {retry} s" if retry else ""),
                              UNREACHABLE, r.status_code)
        if r.status_code < 500:
            raise ClientError(detail, USAGE, r.status_code)
        if r.status_code == DAMAGED_ARTIFACT:
            raise ClientError(f"a file the service stored is damaged and was not used ({detail}); its operator must "
                              "restore it from a backup, resubmitting will not help", JOB_FAILED, r.status_code)
        raise ClientError(f"the service failed ({r.status_code}: {detail})", JOB_FAILED, r.status_code)

    def _unreachable(self, reason: str) -> ClientError:
        return ClientError(f"cannot reach {self.url} ({reason}); is 'neuenh serve' running? "
                           "set --url or NEUENH_URL", UNREACHABLE)


def _reason(exc: Exception) -> str:
    """A transport error in a few words: ``[Errno 111] Connection refused`` -> ``connection refused``."""
    text = str(exc).strip() or type(exc).__name__
    text = re.sub(r"^(\[Errno -?\d+\]\s*)+", "", text.splitlines()[-1]).rstrip(".")
    return text[:1].lower() + text[1:]


def _detail(r: httpx.Response) -> str:
    """The service's ``{"detail": ...}``, or the status line of an answer that is not one."""
    try:
        detail = r.json()["detail"]
    except (ValueError, KeyError, TypeError):
        return f"HTTP {r.status_code} {r.reason_phrase} from {r.request.url.copy_with(query=None)}"
    if isinstance(detail, str):
        return detail
    if isinstance(detail, list):  # FastAPI's own validation errors
        return "; ".join(f"{'.'.join(map(str, d.get('loc', [])))}: {d.get('msg')}" for d in detail
                         if isinstance(d, dict)) or str(detail)
    return str(detail)
