"""The house has floors: each room (a root module or a subpackage of ``toosicubix``) sits on one floor, and an import
never climbs to a higher floor. Rooms on one floor may import each other, but never in a circle.

The order is written once, here (:data:`FLOORS`, lowest first, as the house style's "Layers" gives it). A room
that is not on any floor fails the test, so a new module or package must be placed before it can land.
"""

from __future__ import annotations

import ast
from pathlib import Path

from tests.conftest import REPO

#: Lowest floor first. Data flows up: annotations (schema, model) -> parts -> solver -> formats / evaluation /
#: render -> cli and web.
FLOORS: tuple[tuple[str, ...], ...] = (
    ("__init__", "errors", "fields", "geometry", "jsonfile", "vocabulary"),
    ("camera", "model", "size_priors"),
    ("parts",),
    ("annotations", "solver"),
    ("formats",),
    ("evaluation", "priors", "simulate"),
    ("pipeline",),
    ("render", "web"),
    ("cli", "__main__"),
)
PACKAGE = REPO / "toosicubix"


def _room(module: str) -> str:
    """``toosicubix.solver.lm`` -> ``solver``; ``toosicubix.geometry`` -> ``geometry``; ``toosicubix`` ->
    ``__init__``."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def _module_name(path: Path) -> str:
    parts = path.relative_to(REPO).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports() -> list[tuple[str, str, int, str]]:
    """Every import of a ``toosicubix`` module inside the package: (importing module, imported module, line, file)."""
    found = []
    for path in sorted(PACKAGE.rglob("*.py")):
        module = _module_name(path)
        package = module if path.name == "__init__.py" else module.rpartition(".")[0]
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            targets: list[str] = []
            if isinstance(node, ast.ImportFrom):
                if node.level:
                    base = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                    target = ".".join(base + ([node.module] if node.module else []))
                else:
                    target = node.module or ""
                targets = [target] if node.module else [f"{target}.{a.name}" for a in node.names]
            elif isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            for target in targets:
                if target == "toosicubix" or target.startswith("toosicubix."):
                    found.append((module, target, node.lineno, str(path.relative_to(REPO))))
    return found


def _floor() -> dict[str, int]:
    return {room: level for level, rooms in enumerate(FLOORS) for room in rooms}


def test_every_room_has_a_floor():
    floor = _floor()
    rooms = {_room(_module_name(p)) for p in PACKAGE.rglob("*.py")}
    assert rooms - set(floor) == set(), "place each new module or package on a floor in FLOORS"


def test_no_import_climbs():
    floor = _floor()
    climbs = [f"{file}:{line}: {module} (floor {floor[_room(module)]}) imports {target} "
              f"(floor {floor[_room(target)]})"
              for module, target, line, file in _imports() if floor[_room(target)] > floor[_room(module)]]
    assert climbs == []


def test_rooms_import_no_circle():
    edges: dict[str, set[str]] = {}
    for module, target, _, _ in _imports():
        if _room(module) != _room(target):
            edges.setdefault(_room(module), set()).add(_room(target))
    seen: dict[str, int] = {}  # 1: on the path, 2: done

    def visit(room: str, path: list[str]) -> list[str] | None:
        seen[room] = 1
        for other in sorted(edges.get(room, ())):
            if seen.get(other) == 1:
                return [*path, room, other]
            if other not in seen:
                circle = visit(other, [*path, room])
                if circle:
                    return circle
        seen[room] = 2
        return None

    for room in sorted(edges):
        if room not in seen:
            circle = visit(room, [])
            assert circle is None, " -> ".join(circle)
