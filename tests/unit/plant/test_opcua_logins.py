"""OPC UA logins: wrong passwords held per name over a sliding window (time passed in)."""

from __future__ import annotations

from asyncua.crypto.permission_rules import UserRole

from service.plant.opcua import LOGIN_FAILURES, LOGIN_WINDOW_S, Technicians


def test_a_name_is_held_after_its_wrong_passwords_then_free_again() -> None:
    now = [1000.0]
    users = Technicians({"anna": "s3cret", "ben": "pa55"}, clock=lambda: now[0])
    for _ in range(LOGIN_FAILURES):
        assert users.get_user(None, "anna", "guess") is None
    # Held: even the right password is refused until the window has passed.
    assert users.get_user(None, "anna", "s3cret") is None
    assert "wait" in users.last_refused and "guess" not in users.last_refused
    assert users.get_user(None, "ben", "pa55").role is UserRole.User  # others are not held
    assert users.get_user(None).role is UserRole.Anonymous
    now[0] += LOGIN_WINDOW_S + 0.1
    assert users.get_user(None, "anna", "s3cret").role is UserRole.User


def test_unknown_names_share_one_count() -> None:
    now = [0.0]
    users = Technicians({"anna": "s3cret"}, clock=lambda: now[0])
    for i in range(LOGIN_FAILURES):
        assert users.get_user(None, f"nobody-{i}", "x") is None
    assert users.get_user(None, "someone-else", "x") is None
    assert "wait" in users.last_refused
    assert users.get_user(None, "anna", "s3cret").role is UserRole.User
    assert users.refused == LOGIN_FAILURES + 1
