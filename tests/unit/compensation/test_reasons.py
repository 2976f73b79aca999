"""The runbook's table of reason codes against the codes the compensation can give: each code
the controller, its laws and the runtime can put in the decision log is in
``service.compensation.reasons`` (found in their source, not listed by hand), each there is
one of them, and the operator's runbook holds the table."""

from __future__ import annotations

import ast
from pathlib import Path

from service.compensation.controller import _gate
from service.compensation.reasons import REASONS, by_code, markdown_table
from service.compensation.records import State
from service.measure.result import Status

ROOT = Path(__file__).resolve().parents[3]
DECIDERS = {"_decision": 1, "_enter": 2, "Hold": 0, "_drop": 1}
"""Calls that put a code in the log, and the place of the code among their arguments."""


def literal(node: ast.AST | None) -> str | None:
    return node.value if isinstance(node, ast.Constant) and isinstance(node.value, str) \
        else None


def literals(node: ast.AST) -> set[str]:
    """The codes an argument can be: a literal, or either literal of ``a if c else b``."""
    if isinstance(node, ast.IfExp):
        return literals(node.body) | literals(node.orelse)
    return {literal(node)} - {None}


def codes_in_source() -> set[str]:
    """Every code the source can give: the literal codes of the calls that log one, the
    ``(code, why)`` tuples the refusals return, ``status_<status>`` for every measurement
    status and every hold (``hold_offsets``' codes and the holds the runtime names),
    ``gate_<state>`` for every state that holds judging."""
    codes: set[str] = set()
    holds: set[str] = set()
    for path in (ROOT / "service").rglob("*.py"):
        compensation = path.parent.name == "compensation"
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Call):
                f = node.func
                name = f.attr if isinstance(f, ast.Attribute) else getattr(f, "id", "")
                at = DECIDERS.get(name)
                if at is not None and len(node.args) > at:
                    codes |= literals(node.args[at])
                if name == "hold_offsets":
                    holds |= {literal(k.value) for k in node.keywords if k.arg == "code"}
            elif isinstance(node, ast.FunctionDef) and node.name == "hold_offsets":
                holds.add(literal(node.args.defaults[-1]))
            elif compensation and isinstance(node, ast.Return) \
                    and isinstance(node.value, ast.Tuple) \
                    and len(node.value.elts) == 2 and literal(node.value.elts[0]):
                code = literal(node.value.elts[0])
                if code.replace("_", "").isalpha() and code.islower():
                    codes.add(code)
            elif isinstance(node, ast.Assign) and any(
                    isinstance(t, ast.Name) and t.id in ("held", "hold") for t in node.targets):
                for value in ast.walk(node.value):
                    if literal(value):
                        holds.add(literal(value))
    holds.discard(None)
    codes |= {f"status_{s.value}" for s in Status if s is not Status.OK}
    codes |= {f"status_held_for_{h}" for h in holds}
    codes |= {f"gate_{s.value}" for s in State if _gate(s, 1)}
    return codes


def test_every_code_the_compensation_gives_is_in_the_runbook_table() -> None:
    found = codes_in_source()
    assert {"write", "limit", "status_no_stripe", "status_held_for_master",
            "status_held_for_runout", "gate_alarm"} <= found  # the scan sees each kind
    missing = sorted(found - set(by_code()))
    assert not missing, f"reason codes with no line in service/compensation/reasons.py: {missing}"


def test_the_table_holds_no_code_the_compensation_cannot_give() -> None:
    unknown = sorted(set(by_code()) - codes_in_source())
    assert not unknown, f"reasons no code of the source gives: {unknown}"
    assert len(by_code()) == len(REASONS), "a code twice"


def test_the_operators_runbook_holds_the_table() -> None:
    page = (ROOT / "docs" / "runbooks.md").read_text()
    assert markdown_table() in page, \
        "docs/runbooks.md differs from python -m service.compensation.reasons: paste it"
