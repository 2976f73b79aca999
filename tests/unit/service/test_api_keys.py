"""API keys kept as hashes: ``shaftgauge api-key add`` prints a key once and the file keeps
its SHA-256 alone; the service takes that key for its role; removed, it is refused."""

from __future__ import annotations

import json
import stat

import pytest
from fastapi.testclient import TestClient

from calib_store import api_keys
from service import cli
from service.api.app import create_app
from service.serve import Children, build
from tests.unit.service.conftest import make_settings


def _cli(capsys, *args: str) -> tuple[int, str]:
    code = cli.main(list(args))
    out, err = capsys.readouterr()
    return code, out if code == 0 else err


def test_the_key_file_holds_no_key_and_is_private(tmp_path, capsys) -> None:
    path = tmp_path / "api-keys.json"
    code, out = _cli(capsys, "api-key", "add", "--role", "technician", "--note", "anna",
                     "--key-file", str(path))
    assert code == 0
    shown = json.loads(out)
    text = path.read_text()
    assert shown["key"] not in text and api_keys.digest(shown["key"]) in text
    assert len(shown["key"]) >= 32
    assert stat.S_IMODE(path.stat().st_mode) == 0o600
    code, out = _cli(capsys, "api-key", "list", "--key-file", str(path))
    assert json.loads(out) == [{"id": shown["id"], "role": "technician",
                                "created": json.loads(text)["keys"][0]["created"],
                                "note": "anna"}]
    assert shown["key"] not in out
    assert api_keys.match(path, shown["key"]).id == shown["id"]
    assert api_keys.match(path, shown["key"] + "x") is None


def test_the_service_takes_a_hashed_key_for_its_role_until_it_is_removed(tmp_path,
                                                                       capsys) -> None:
    path = tmp_path / "api-keys.json"
    entry, key = api_keys.add(path, "technician")
    gauge, _ = build(make_settings(tmp_path, api={"key_file": str(path)}), Children())
    with TestClient(create_app(gauge)) as c:
        put = {"json": {"shadow": True}, "headers": {"X-API-Key": key}}
        assert c.put("/api/v1/compensation/shadow", **put).status_code == 200
        log = c.get("/api/v1/compensation/log", params={"kinds": "settings"}).json()["items"]
        # the audit names the key by its id and the client, never the key
        assert log[0]["who"] == f"api:technician (key {entry.id}, testclient)"
        _, op_key = api_keys.add(path, "operator")
        r = c.put("/api/v1/compensation/shadow", json={"shadow": True},
                  headers={"X-API-Key": op_key})
        assert r.status_code == 403  # read again when the file changed: a known, lower key
        code, _ = _cli(capsys, "api-key", "remove", entry.id, "--key-file", str(path))
        assert code == 0
        assert c.put("/api/v1/compensation/shadow", **put).status_code == 401


@pytest.mark.parametrize("content", ["not json", '{"keys": [{"id": 1}]}'])
def test_a_broken_key_file_is_named(tmp_path, capsys, content: str) -> None:
    path = tmp_path / "api-keys.json"
    path.write_text(content)
    code, err = _cli(capsys, "api-key", "list", "--key-file", str(path))
    assert code != 0 and str(path) in err and "Traceback" not in err
    assert api_keys.match(path, "any key at all, even a long one") is None  # no 500
    with pytest.raises(SystemExit) as done:  # argparse names the roles it takes
        cli.main(["api-key", "add", "--role", "wizard", "--key-file", str(path)])
    assert done.value.code == 2 and "operator" in capsys.readouterr().err
