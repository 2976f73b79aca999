"""ARCHITECTURE.md's rules, checked: dependencies point one way (pure core <- adapters <-
application), no class over 300 lines, no API module over 150 lines."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
# The pure core: numerics and state machines, no I/O, nothing of the adapters or the app.
CORE = ["service/measure", "service/quality", "service/compensation",
        "service/measurement_record.py",
        "service/calibrate/board.py",
        "service/calibrate/intrinsics.py", "service/calibrate/plane.py",
        "service/calibrate/axis.py", "service/calibrate/report.py",
        "service/calibrate/master.py", "service/calibrate/laser_line.py"]
CORE_MODULES = ("service.measure", "service.quality", "service.compensation",
                "service.measurement_record",
                "service.calibrate.board",
                "service.calibrate.intrinsics", "service.calibrate.plane",
                "service.calibrate.axis", "service.calibrate.report",
                "service.calibrate.master", "service.calibrate.laser_line")


def files(*parts: str) -> list[Path]:
    out: list[Path] = []
    for part in parts:
        p = ROOT / part
        out += sorted(p.rglob("*.py")) if p.is_dir() else [p]
    return out


def imports(path: Path) -> set[str]:
    """Every module a file imports (at any depth: lazy imports count too)."""
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.add(node.module)
        elif isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
    return found


def ours(module: str) -> bool:
    return module.split(".")[0] in ("service", "drivers", "calib_store")


@pytest.mark.parametrize("path", files(*CORE), ids=str)
def test_the_core_imports_only_the_core(path: Path) -> None:
    bad = {m for m in imports(path) if ours(m) and not m.startswith(CORE_MODULES)}
    assert not bad, f"{path.relative_to(ROOT)} imports {bad}"


@pytest.mark.parametrize("path", files("calib_store", "drivers"), ids=str)
def test_adapters_import_only_the_core_and_adapters(path: Path) -> None:
    bad = {m for m in imports(path) if m.startswith("service") and
           not m.startswith(CORE_MODULES)}
    assert not bad, f"{path.relative_to(ROOT)} imports {bad} (the application)"


@pytest.mark.parametrize("path", files("calib_store"), ids=str)
def test_the_store_imports_nothing_from_service(path: Path) -> None:
    bad = {m for m in imports(path) if m.startswith("service")}
    assert not bad, f"{path.relative_to(ROOT)} imports {bad}"


def test_no_class_over_300_lines() -> None:
    long = []
    for path in files("service", "drivers", "calib_store"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ClassDef) and node.end_lineno - node.lineno + 1 > 300:
                long.append(f"{path.relative_to(ROOT)}:{node.name} "
                            f"({node.end_lineno - node.lineno + 1} lines)")
    assert not long, long


def test_no_api_module_over_150_lines() -> None:
    long = [f"{p.relative_to(ROOT)} ({n} lines)" for p in files("service/api")
            if (n := len(p.read_text().splitlines())) > 150]
    assert not long, long


def test_the_aqdef_writer_is_pure() -> None:
    path = ROOT / "service/plant/aqdef.py"
    bad = {m for m in imports(path) if ours(m) or m in ("os", "socket", "pathlib", "sqlite3")}
    assert not bad, bad


@pytest.mark.parametrize("path", files("service/plant"), ids=str)
def test_plant_links_do_not_reach_into_the_api_or_the_wiring(path: Path) -> None:
    bad = {m for m in imports(path) if m.startswith(("service.api", "service.serve",
                                                     "service.cli", "service.runtime"))}
    assert not bad, f"{path.relative_to(ROOT)} imports {bad} (plant links sit below the runtime)"


def module_graph() -> dict[str, set[str]]:
    """Each of our modules and ours it imports (a name imported from a package counts as its
    module when it is one; lazy and type-checking imports count)."""
    mods = {}
    for path in files("service", "drivers", "calib_store"):
        name = ".".join(path.relative_to(ROOT).with_suffix("").parts)
        mods[name.removesuffix(".__init__")] = path
    graph = {}
    for name, path in mods.items():
        deps = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                deps |= {node.module} & mods.keys()
                deps |= {f"{node.module}.{a.name}" for a in node.names} & mods.keys()
            elif isinstance(node, ast.Import):
                deps |= {a.name for a in node.names} & mods.keys()
        graph[name] = deps - {name}
    return graph


def test_no_two_modules_import_each_other() -> None:
    """No cycle of imports, at any length (shared types belong in a lower module)."""
    graph, state, cycles = module_graph(), {}, []

    def visit(node: str, path: list[str]) -> None:
        state[node] = "open"
        for dep in sorted(graph[node]):
            if state.get(dep) == "open":
                cycles.append(" -> ".join([*path[path.index(dep):], dep]))
            elif dep not in state:
                visit(dep, [*path, dep])
        state[node] = "done"

    for node in sorted(graph):
        if node not in state:
            visit(node, [node])
    assert not cycles, cycles


SUBSCRIBE = ("on_decision", "on_settings", "on_publish", "on_change", "on_new_job", "on_part",
             "on_write")
"""The running service's subscriptions (each publisher keeps a ``Listeners``)."""


def _subscriptions(path: Path) -> list[tuple[int, str, bool]]:
    """(line, method, inside a constructor) of each subscription made in ``path``."""
    tree = ast.parse(path.read_text())
    inits = [n for n in ast.walk(tree) if isinstance(n, ast.FunctionDef) and n.name == "__init__"]
    in_init = {id(c) for n in inits for c in ast.walk(n)}
    return [(c.lineno, c.func.attr, id(c) in in_init) for c in ast.walk(tree)
            if isinstance(c, ast.Call) and isinstance(c.func, ast.Attribute)
            and c.func.attr in SUBSCRIBE   # a part calling back its own owner is no subscription
            and not (isinstance(c.func.value, ast.Name) and c.func.value.id == "self")]


def test_subscriptions_are_made_in_one_place_never_by_a_constructor() -> None:
    """One owner wires the flow (``service.serve.wire``): a reader finds every subscription
    there, and no part starts listening by being made."""
    wiring = ROOT / "service" / "serve.py"
    for path in (ROOT / "service").rglob("*.py"):
        subs = _subscriptions(path)
        assert not [s for s in subs if s[2]], f"{path}: a constructor subscribes: {subs}"
        if path != wiring:
            assert not subs, f"{path}: subscriptions outside service/serve.py: {subs}"


def test_every_publisher_keeps_its_listeners_in_the_one_listener_type() -> None:
    """No hand-made list of callables: ``service.runtime.listeners.Listeners`` tells each
    listener, and one that raises does not silence the others."""
    for path in (ROOT / "service").rglob("*.py"):
        if path.name == "listeners.py":
            continue
        text = path.read_text()
        assert "_listeners: list[" not in text and "listeners: list[Callable" not in text, path


def test_no_two_modules_share_a_file_name_but_api_routers() -> None:
    """A file's name says which of its kind it is: the offset channel is not the register
    map's offsets, the job's owner not its store (an API router may share its resource's
    name)."""
    seen: dict[str, list[str]] = {}
    for top in ("service", "drivers", "calib_store"):
        for path in (ROOT / top).rglob("*.py"):
            if path.name != "__init__.py" and path.parent.name != "api":
                seen.setdefault(path.name, []).append(str(path.relative_to(ROOT)))
    assert not {n: p for n, p in seen.items() if len(p) > 1}


def test_every_on_measurement_takes_the_measurement_then_the_time_then_the_feature() -> None:
    """One signature: ``on_measurement(m[, now][, feature])`` wherever a measurement is
    judged (the controller, an entry's, the job's, the channel's)."""
    found = []
    for path in (ROOT / "service").rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef) \
                    and node.name == "on_measurement":
                names = [a.arg for a in node.args.args][1:]
                found.append((path.name, names))
                assert names[0] == "m", (path, names)
                assert names[1:2] in (["now"], ["feature"], ["feature_number"]), (path, names)
                assert names[-1] in ("now", "feature", "feature_number"), (path, names)
    assert len(found) >= 4, found
