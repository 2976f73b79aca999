"""Settings: TOML file, environment overrides, errors that name the setting."""

from __future__ import annotations

import pydantic
import pytest

from service.config import ConfigError, load_settings


def test_defaults_are_the_simulated_system() -> None:
    s = load_settings()
    assert s.camera.source == "sim" and s.plc.source == "sim"
    assert s.modbus.port == 5020 and s.api.port == 8000 and s.compensation.shadow


def test_file_and_environment(tmp_path, monkeypatch) -> None:
    f = tmp_path / "c.toml"
    f.write_text('[modbus]\nport = 1502\n[api]\nport = 8123\n[compensation]\nnominal_mm = 25.0\n')
    monkeypatch.setenv("SHAFTGAUGE_API__PORT", "9000")
    monkeypatch.setenv("SHAFTGAUGE_API__KEYS", '{"0123456789abcdef0123": "admin"}')
    s = load_settings(f)
    assert s.modbus.port == 1502 and s.api.port == 9000  # the environment wins
    assert s.compensation.nominal_mm == 25.0
    assert s.api.keys == {"0123456789abcdef0123": "admin"}


@pytest.mark.parametrize(("toml", "words"), [
    ("[modbus]\nport = 70000\n", "modbus.port"),
    ("[camera]\nsource = 'usb'\n", "camera.source"),
    ("[api]\nread_networks = ['nowhere']\n", "api.read_networks"),
    ("[api]\nkeys = {short = 'admin'}\n", "api.keys"),
    ("[compensation]\nshadow = 'maybe'\n", "compensation.shadow"),
    ("[camera]\nframe_rate = 3\n", "camera.frame_rate"),
    ("[compensation]\nsurprise = 1\n", "compensation.surprise"),
    ("[compensation]\nmax_step_mm = 0.5\nmax_total_mm = 0.1\n", "max_step_mm"),
    ("[modbus\nport = 1\n", "not valid TOML"),
    ("[plc]\ntls = {certfile = 'a', keyfile = 'b', cafile = 'c'}\n", "source = \"modbus\""),
    ("[modbus]\ntls = {certfile = 'a', keyfile = 'b'}\n", "modbus.tls.cafile"),
    ("[api]\ntls_keyfile = 'k.pem'\n", "tls_certfile and tls_keyfile go together"),
    ("[opcua]\nnone_security = 'sometimes'\n", "opcua.none_security"),
])
def test_bad_settings_name_the_setting(tmp_path, toml, words) -> None:
    f = tmp_path / "c.toml"
    f.write_text(toml)
    with pytest.raises(ConfigError) as err:
        load_settings(f)
    assert words in str(err.value) and str(f) in str(err.value)


def test_bad_environment_names_the_setting(monkeypatch) -> None:
    monkeypatch.setenv("SHAFTGAUGE_MEASUREMENT__WORKERS", "zero")
    with pytest.raises(ConfigError, match=r"measurement\.workers"):
        load_settings()


def test_missing_file(tmp_path) -> None:
    with pytest.raises(ConfigError, match="cannot read"):
        load_settings(tmp_path / "nope.toml")


def test_settings_are_frozen_after_load() -> None:
    """Changes at run time go through their owner (and are kept), never into the settings."""
    s = load_settings()
    with pytest.raises(pydantic.ValidationError, match="frozen"):
        s.api.port = 1
    with pytest.raises(pydantic.ValidationError, match="frozen"):
        s.log_level = "debug"


@pytest.mark.parametrize(("keys", "words"), [
    ('{"0123456789abcdefSECRET": "wizard"}', "api.keys.<a key>: Input should be"),
    ('{"SECRET": "admin", "0123456789abcdef0123": "admin"}', "1 of the 2 are shorter"),
    ('{"0123456789abcdefSECRET": "admin"', "must be JSON"),  # not JSON: no traceback
])
def test_a_config_error_never_prints_a_key(monkeypatch, keys: str, words: str) -> None:
    monkeypatch.setenv("SHAFTGAUGE_API__KEYS", keys)
    with pytest.raises(ConfigError) as err:
        load_settings()
    text = str(err.value)
    assert words in text and "SECRET" not in text and "0123" not in text, text
