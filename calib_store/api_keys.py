"""API keys kept as hashes (the service's ``api.key_file``): the file holds each key's id,
role and SHA-256, never the key, which ``shaftgauge api-key add`` prints once.

The keys are random (32 URL-safe characters, 192 bits), so a plain SHA-256 is as good as a
slow hash here: nobody can try 2^192 of them. A presented key is hashed once and compared with
every stored hash in constant time. The file is read again when it changes.
"""

from __future__ import annotations

import hashlib
import hmac
import json
import logging
import os
import secrets
import time
from dataclasses import dataclass
from pathlib import Path

ROLES = ("operator", "technician", "admin")
log = logging.getLogger("shaftgauge.api")


class KeyFileError(RuntimeError):
    """The key file cannot be read or written; the message says which and why."""


@dataclass(frozen=True)
class StoredKey:
    """One key as the file keeps it."""

    id: str
    role: str
    sha256: str
    created: str
    note: str = ""


def digest(key: str) -> str:
    """The key's SHA-256, hex."""
    return hashlib.sha256(key.encode()).hexdigest()


def read(path: Path) -> list[StoredKey]:
    """The keys in the file ([] when it does not exist)."""
    if not path.exists():
        return []
    try:
        doc = json.loads(path.read_text())
        return [StoredKey(**k) for k in doc["keys"]]
    except (OSError, ValueError, KeyError, TypeError) as err:
        raise KeyFileError(f"API key file {path} cannot be read: {err}") from None


def _write(path: Path, keys: list[StoredKey]) -> None:
    text = json.dumps({"keys": [k.__dict__ for k in keys]}, indent=1)
    tmp = path.with_name(path.name + ".tmp")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
        with os.fdopen(fd, "w") as f:
            f.write(text)
        if path.exists():
            os.chmod(tmp, path.stat().st_mode & 0o777)
        os.replace(tmp, path)
    except OSError as err:
        raise KeyFileError(f"API key file {path} cannot be written: {err.strerror}") from None


def add(path: Path, role: str, note: str = "") -> tuple[StoredKey, str]:
    """A new random key of ``role``: its entry (kept) and the key itself (shown once)."""
    if role not in ROLES:
        raise KeyFileError(f"role {role!r} is none of {', '.join(ROLES)}")
    keys = read(path)
    key = secrets.token_urlsafe(24)
    entry = StoredKey(id=f"k-{secrets.token_hex(3)}", role=role, sha256=digest(key),
                      created=time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), note=note)
    _write(path, [*keys, entry])
    return entry, key


def remove(path: Path, key_id: str) -> bool:
    """Drop the key ``key_id``; whether there was one."""
    keys = read(path)
    kept = [k for k in keys if k.id != key_id]
    if len(kept) != len(keys):
        _write(path, kept)
    return len(kept) != len(keys)


_cache: dict[Path, tuple[tuple[int, int], list[StoredKey]]] = {}


def match(path: Path, key: str) -> StoredKey | None:
    """The stored key ``key`` is (every hash compared, in constant time), or None."""
    try:
        st = path.stat()
    except OSError:
        return None
    stamp = (st.st_mtime_ns, st.st_size)
    cached = _cache.get(path)
    if cached is None or cached[0] != stamp:
        # A file broken meanwhile (a bad hand edit) takes no key until it is mended: the
        # caller's 401 says the key is unknown, the service's log says why.
        try:
            keys = read(path)
        except KeyFileError as err:
            log.error("%s", err)
            keys = []
        cached = _cache[path] = (stamp, keys)
    given = digest(key).encode()
    found = None
    for k in cached[1]:
        if hmac.compare_digest(k.sha256.encode(), given):
            found = k
    return found
