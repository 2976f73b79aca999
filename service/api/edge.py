"""What every HTTP answer carries, and which ``Host`` names are served.

``SecurityHeaders`` is plain ASGI middleware:
- the ``Host`` header must be an address (any IP literal: a DNS-rebinding page comes with a
  name of its own), ``localhost``, this machine's name or one of ``api.trusted_hosts``;
  others get 400 and nothing else (a page on another site that resolved its name to the
  gauge cannot read the open data);
- every answer says ``X-Content-Type-Options: nosniff``, ``X-Frame-Options: DENY``, no
  referrer, and a Content-Security-Policy that allows nothing but the gauge itself (the
  dashboard loads no inline script; the manual, MkDocs' theme, needs its inline lines);
  over HTTPS also Strict-Transport-Security.
"""

from __future__ import annotations

import ipaddress
import json
import socket
from collections.abc import Iterable

from service.api.limits import ASGIApp, Receive, Scope, Send

_CSP = ("default-src 'self'; img-src 'self' data: blob:; script-src 'self'{inline}; "
        "style-src 'self'{inline}; connect-src 'self'; frame-ancestors 'none'; "
        "base-uri 'none'; form-action 'self'")
_HEADERS = [(b"x-content-type-options", b"nosniff"), (b"x-frame-options", b"DENY"),
            (b"referrer-policy", b"no-referrer")]


def _is_address(host: str) -> bool:
    try:
        ipaddress.ip_address(host.strip("[]"))
    except ValueError:
        return False
    return True


def host_names(trusted: Iterable[str]) -> frozenset[str]:
    """The names served: ``localhost``, this machine's (short and full) and ``trusted``."""
    names = {"localhost", socket.gethostname(), socket.getfqdn(), *trusted}
    return frozenset(n.lower().rstrip(".") for n in names if n)


def _host_of(scope: Scope) -> str:
    for name, value in scope.get("headers", ()):
        if name == b"host":
            text = value.decode("latin-1").strip().lower()
            if text.startswith("["):  # [::1]:8000
                return text.split("]")[0] + "]"
            return text.rsplit(":", 1)[0] if text.count(":") == 1 else text
    return ""


class SecurityHeaders:
    """ASGI middleware: the ``Host`` check and the headers every answer carries."""

    def __init__(self, app: ASGIApp, trusted_hosts: Iterable[str] = ()) -> None:
        self.app = app
        self.names = host_names(trusted_hosts)

    def allowed(self, host: str) -> bool:
        """Whether a request naming ``host`` is served."""
        host = host.rstrip(".")
        return _is_address(host) or host in self.names

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        host = _host_of(scope)
        in_process = (scope.get("client") or ("",))[0] == "testclient"  # FastAPI's TestClient
        if not (in_process or self.allowed(host)):
            body = json.dumps({"detail": f"this gauge does not answer to the host name "
                               f"{host!r}: add it to api.trusted_hosts"}).encode()
            await send({"type": "http.response.start", "status": 400,
                        "headers": [(b"content-type", b"application/json"),
                                    (b"content-length", str(len(body)).encode()), *_HEADERS]})
            await send({"type": "http.response.body", "body": body})
            return
        manual = scope.get("path", "").startswith("/ui/manual")
        csp = _CSP.format(inline=" 'unsafe-inline'" if manual else "").encode()
        secure = scope.get("scheme") == "https"

        async def with_headers(message: dict) -> None:
            if message["type"] == "http.response.start":
                headers = list(message.get("headers", []))
                headers += [*_HEADERS, (b"content-security-policy", csp)]
                if secure:
                    headers.append((b"strict-transport-security", b"max-age=31536000"))
                message = {**message, "headers": headers}
            await send(message)

        await self.app(scope, receive, with_headers)
