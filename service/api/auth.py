"""Who may do what: reading is open on the plant network (configurable); changing anything
needs an API key whose role is high enough. Keys are compared in constant time."""

from __future__ import annotations

import hmac
import ipaddress
from collections.abc import Callable
from typing import Literal

from fastapi import HTTPException, Request, status

from service.config import ApiSettings

Role = Literal["operator", "technician", "admin"]
RANK = {"operator": 0, "technician": 1, "admin": 2}
KEY_HEADER = "X-API-Key"


def role_of(api: ApiSettings, key: str | None) -> Role | None:
    """The role of a key, comparing against every configured key in constant time."""
    if not key:
        return None
    found: Role | None = None
    given = key.encode()
    for candidate, role in api.keys.items():
        if hmac.compare_digest(candidate.encode(), given):
            found = role
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
        if role_of(api, request.headers.get(KEY_HEADER)) is None:
            raise HTTPException(status.HTTP_401_UNAUTHORIZED,
                                f"reading from this address needs a valid {KEY_HEADER} header")

    return dependency


def requires(api: ApiSettings, role: Role) -> Callable[[Request], Role]:
    """Dependency: a key of at least ``role`` (401 without a valid key, 403 if too low)."""

    def dependency(request: Request) -> Role:
        key = request.headers.get(KEY_HEADER)
        have = role_of(api, key)
        if have is None:
            raise HTTPException(status.HTTP_401_UNAUTHORIZED,
                                f"this needs a valid {KEY_HEADER} header ({role} or above)"
                                if key else f"this needs an {KEY_HEADER} header ({role} or "
                                "above)")
        if RANK[have] < RANK[role]:
            raise HTTPException(status.HTTP_403_FORBIDDEN,
                                f"this needs the {role} role; the key has {have}")
        return have

    return dependency
