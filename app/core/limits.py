"""A limit on request bodies: refused with 413 before (or while) the body is read."""

from __future__ import annotations

from starlette.exceptions import HTTPException
from starlette.responses import JSONResponse
from starlette.types import ASGIApp, Message, Receive, Scope, Send


class BodySizeLimit:
    """Refuse bodies larger than ``max_bytes``: by Content-Length up front, else while streaming
    (chunked uploads), so an oversized upload is never stored."""

    def __init__(self, app: ASGIApp, max_bytes: int) -> None:
        self.app = app
        self.max_bytes = max_bytes

    def _sentence(self) -> str:
        return (
            f"The request is larger than the limit of {self.max_bytes / 2**20:g} MiB "
            "(WELDPOOL_MAX_REQUEST_MB); send fewer or smaller files per request."
        )

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        declared = dict(scope["headers"]).get(b"content-length")
        if declared is not None and declared.isdigit() and int(declared) > self.max_bytes:
            await JSONResponse({"detail": self._sentence()}, status_code=413)(scope, receive, send)
            return
        received = 0

        async def counting_receive() -> Message:
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > self.max_bytes:
                    raise HTTPException(413, self._sentence())
            return message

        await self.app(scope, counting_receive, send)
