"""Who may do what: reading is open on the plant network (configurable); changing anything
needs an API key whose role is high enough: one of ``api.keys`` or of the hashed
``api.key_file`` (``calib_store.api_keys``), compared in constant time. An address that sends
too many wrong keys gets 429 for a while (``service.api.attempts``); every wrong key is
logged with the address, never the key. A change is done by a ``Caller``: the role, which key
(its id in the key file, or its place in ``api.keys``) and the client's address, as the audit
names it."""

from __future__ import annotations

import hmac
import ipaddress
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

from fastapi import HTTPException, Request, status

from calib_store import api_keys
from service.api.attempts import attempts_for
from service.config import ApiSettings

Role = Literal["operator", "technician", "admin"]
RANK = {"operator": 0, "technician": 1, "admin": 2}
KEY_HEADER = "X-API-Key"
log = logging.getLogger("shaftgauge.api")


@dataclass(frozen=True)
class Caller:
    """Who asked for a change: ``str(caller)`` is what the audit and the decision log keep."""

    role: Role
    key_id: str
    client: str

    def __str__(self) -> str:
        return f"{self.role} (key {self.key_id}, {self.client})"


def _client(request: Request) -> str:
    return request.client.host if request.client else "?"


def _checked(api: ApiSettings, request: Request, key: str | None) -> Caller | None:
    """``identify`` for a request: 429 while its address is locked out, each wrong key counted
    and logged with the address."""
    if not key:
        return None
    client = _client(request)
    attempts, now = attempts_for(api), time.monotonic()
    wait = attempts.retry_after(client, now)
    if wait > 0:
        raise HTTPException(status.HTTP_429_TOO_MANY_REQUESTS,
                            f"{attempts.max_failures} wrong keys from {client} within "
                            f"{attempts.window_s:.0f} s: try again in {math.ceil(wait)} s",
                            headers={"Retry-After": str(math.ceil(wait))})
    found = identify(api, key)
    if found is None:
        n = attempts.failed(client, now)
        log.warning("api: a wrong %s from %s (%d within %.0f s)", KEY_HEADER, client, n,
                    attempts.window_s)
        return None
    return Caller(found[0], found[1], client)


def identify(api: ApiSettings, key: str | None) -> tuple[Role, str] | None:
    """The role and the id of a key (``api.keys#N`` for the N-th configured key, never the key
    itself), comparing against every key in constant time."""
    if not key:
        return None
    found: tuple[Role, str] | None = None
    given = key.encode()
    for n, (candidate, role) in enumerate(api.keys.items(), start=1):
        if hmac.compare_digest(candidate.encode(), given):
            found = (role, f"api.keys#{n}")
    stored = api_keys.match(api.key_file, key) if api.key_file else None
    if found is None and stored is not None:
        found = (stored.role, stored.id)  # type: ignore[assignment]
    return found


def _client_may_read(api: ApiSettings, request: Request) -> bool:
    if not api.open_read:
        return False
    host = request.client.host if request.client else ""
    try:
        addr = ipaddress.ip_address(host)
    except ValueError:
        return host == "testclient"  # FastAPI's in-process test client
    return any(addr in ipaddress.ip_network(n, strict=False) for n in api.read_networks)


def reader(api: ApiSettings) -> Callable[[Request], None]:
    """Dependency: reading is open on the read networks, else any valid key is needed."""

    def dependency(request: Request) -> None:
        if _client_may_read(api, request):
            return
        if _checked(api, request, request.headers.get(KEY_HEADER)) is None:
            raise HTTPException(status.HTTP_401_UNAUTHORIZED,
                                f"reading from this address needs a valid {KEY_HEADER} header")

    return dependency


def requires(api: ApiSettings, role: Role) -> Callable[[Request], Caller]:
    """Dependency: a key of at least ``role`` (401 without a valid key, 403 if too low)."""

    def dependency(request: Request) -> Caller:
        key = request.headers.get(KEY_HEADER)
        caller = _checked(api, request, key)
        if caller is None:
            raise HTTPException(status.HTTP_401_UNAUTHORIZED,
                                f"this needs a valid {KEY_HEADER} header ({role} or above)"
                                if key else f"this needs an {KEY_HEADER} header ({role} or "
                                "above)")
        if RANK[caller.role] < RANK[role]:
            raise HTTPException(status.HTTP_403_FORBIDDEN,
                                f"this needs the {role} role; the key has {caller.role}")
        return caller

    return dependency
