"""The HTTP edge's limits: request bodies are bounded before anything reads them (before
routing and access checks), and uploaded PNG images are checked from their header before any
pixel is decoded.

``BodyLimit`` is plain ASGI middleware: a declared ``Content-Length`` above the limit is
answered 413 at once; a body sent without one (chunked) is counted as it arrives and cut off
with 413 at the limit. Nothing beyond the limit is ever held in memory.
"""

from __future__ import annotations

import json
import re
import struct
from collections.abc import Awaitable, Callable, MutableMapping
from typing import Any

from fastapi import HTTPException

Scope = MutableMapping[str, Any]
Message = MutableMapping[str, Any]
Receive = Callable[[], Awaitable[Message]]
Send = Callable[[Message], Awaitable[None]]
ASGIApp = Callable[[Scope, Receive, Send], Awaitable[None]]

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _too_large(limit: int) -> str:
    return f"the request body is larger than this endpoint takes ({limit} bytes)"


class BodyLimit:
    """ASGI middleware bounding request bodies.

    Parameters
    ----------
    app : ASGI app
        The application.
    default_bytes : int
        Limit for every request.
    larger : list of (regex, int)
        Paths (matched from their start) that take more, e.g. image uploads.
    """

    def __init__(self, app: ASGIApp, default_bytes: int,
                 larger: list[tuple[str, int]] | None = None) -> None:
        self.app = app
        self.default_bytes = default_bytes
        self.larger = [(re.compile(p), n) for p, n in (larger or [])]

    def limit_for(self, path: str) -> int:
        """The body limit of a path, bytes."""
        for pattern, n in self.larger:
            if pattern.match(path):
                return n
        return self.default_bytes

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        limit = self.limit_for(scope.get("path", ""))
        declared = None
        for name, value in scope.get("headers", []):
            if name == b"content-length":
                declared = value
        if declared is not None:
            if not declared.isdigit():
                await _reply(send, 400, "Content-Length is not a number")
                return
            if int(declared) > limit:
                await _reply(send, 413, _too_large(limit))
                return
        received = 0
        started = False

        async def counted() -> Message:
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > limit:
                    raise HTTPException(413, _too_large(limit))
            return message

        async def watched(message: Message) -> None:
            nonlocal started
            if message["type"] == "http.response.start":
                started = True
            await send(message)

        try:
            await self.app(scope, counted, watched)
        except HTTPException as err:  # raised by ``counted`` outside any route's handling
            if err.status_code != 413 or started:
                raise
            await _reply(send, 413, str(err.detail))


async def _reply(send: Send, status: int, detail: str) -> None:
    body = json.dumps({"detail": detail}).encode()
    await send({"type": "http.response.start", "status": status,
                "headers": [(b"content-type", b"application/json"),
                            (b"content-length", str(len(body)).encode()),
                            (b"connection", b"close")]})
    await send({"type": "http.response.body", "body": body})


def png_size(data: bytes) -> tuple[int, int]:
    """(width, height) from a PNG's header, without decoding it.

    Raises
    ------
    HTTPException
        415 when the data is not a PNG, 422 when its header is damaged.
    """
    if data[:8] != PNG_SIGNATURE:
        raise HTTPException(415, "the body is not a PNG image (it does not start with the PNG "
                            "signature); send the image as PNG")
    if len(data) < 24 or data[12:16] != b"IHDR":
        raise HTTPException(422, "the PNG has no valid IHDR header")
    width, height = struct.unpack(">II", data[16:24])
    if width == 0 or height == 0:
        raise HTTPException(422, f"the PNG declares an empty image ({width}x{height})")
    return width, height


def check_image_size(size: tuple[int, int], expected: tuple[int, int] | None,
                     max_pixels: int) -> None:
    """Refuse (422) an image whose declared size is not the camera's, or, with no camera size
    known, one larger than ``max_pixels``."""
    w, h = size
    if expected is not None and (w, h) != tuple(expected):
        raise HTTPException(422, f"the image is {w}x{h} pixels; this camera's images are "
                            f"{expected[0]}x{expected[1]}")
    if w * h > max_pixels:
        raise HTTPException(422, f"the image is {w}x{h} pixels, more than "
                            f"{max_pixels} pixels")
