"""Connections the service will not let an idle or slow client hold.

uvicorn counts every open connection against ``limit_concurrency`` and answers 503 to *every*
request, ``/health`` included, once the count is reached; a connection that never sends a byte
has no timeout of its own (the keep-alive timer starts only after a first response). 260 idle TCP
connections took the service down for as long as they were held (issue 17).

``HeadDeadlineProtocol`` is uvicorn's h11 protocol with a deadline for each request head: a
connection must deliver a complete request line and headers within ``head_timeout`` seconds of
opening, or of the first byte of a later request, or it is closed. Between requests, uvicorn's
keep-alive timeout closes an idle connection (75 s: pollers reuse theirs). Slow bodies of a
request already under way are not cut (an upload's pace is the client's network's).
"""

from __future__ import annotations

import asyncio

from uvicorn.config import Config
from uvicorn.protocols.http.h11_impl import H11Protocol
from uvicorn.server import ServerState


class HeadDeadlineProtocol(H11Protocol):
    head_timeout: float = 10.0  # seconds; ``protocol()`` makes a subclass with another value

    def __init__(self, config: Config, server_state: ServerState, app_state: dict,
                 _loop: asyncio.AbstractEventLoop | None = None) -> None:
        super().__init__(config, server_state, app_state, _loop)
        self._deadline: asyncio.TimerHandle | None = None
        self._waiting_after = None  # the cycle that was current when the deadline was set

    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        super().connection_made(transport)
        self._arm()

    def data_received(self, data: bytes) -> None:
        super().data_received(data)
        if self.cycle is not self._waiting_after:  # a new request's head is complete
            self._disarm()
            self._waiting_after = self.cycle
        elif self._deadline is None and self._between_requests() and not self.transport.is_closing():
            self._arm()  # the first bytes of the next head, after a response: the head has a deadline

    def connection_lost(self, exc: Exception | None) -> None:
        self._disarm()
        super().connection_lost(exc)

    def _arm(self) -> None:
        self._disarm()
        self._deadline = self.loop.call_later(self.head_timeout, self._expire)

    def _disarm(self) -> None:
        if self._deadline is not None:
            self._deadline.cancel()
            self._deadline = None

    def _between_requests(self) -> bool:
        return self.cycle is None or self.cycle.response_complete

    def _expire(self) -> None:
        self._deadline = None
        if self.cycle is self._waiting_after and self._between_requests() and not self.transport.is_closing():
            self.transport.close()


def protocol(head_timeout: float) -> type[HeadDeadlineProtocol]:
    """The protocol class for ``uvicorn.Config(http=...)`` with this request-head deadline."""
    return type("HeadDeadlineProtocol", (HeadDeadlineProtocol,), {"head_timeout": head_timeout})
