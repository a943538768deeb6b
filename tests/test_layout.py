"""The package's rooms import only what the README's Layout section allows them to."""

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "roto_trl"
PROGRAMS = {"train", "evaluate", "analyse", "record", "sweep", "random_rollout"}
# room -> the rooms of ours it may import (utils is open to every room); ``config`` (the schema,
# roto_trl/config.py) sits beside the programs and is open to the rooms that build from a config
ALLOWED = {
    "utils": set(),
    "transforms": set(),
    "envs": {"transforms"},
    "modules": set(),
    "objectives": {"modules"},
    "data": set(),
    "trainers": {"config", "envs", "transforms", "modules", "objectives", "data"},
    "analysis": {"config", "envs", "transforms", "modules", "objectives", "data", "trainers"},
    "sweeps": {"analysis"},
}
CONFIG_MAY_IMPORT = {"envs", "modules"}


def imported_rooms(path: Path) -> set[str]:
    """The first component under ``roto_trl`` of every module that ``path`` imports."""
    rooms = set()
    for node in ast.walk(ast.parse(path.read_text())):
        names = []
        if isinstance(node, ast.ImportFrom) and node.module:
            names = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
        elif isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        for name in names:
            parts = name.split(".")
            if parts[0] == "roto_trl" and len(parts) > 1:
                rooms.add(parts[1])
    return rooms


def test_top_level_holds_only_programs_and_the_face():
    modules = {p.stem for p in PACKAGE.glob("*.py")}
    assert modules == PROGRAMS | {"__init__", "config"}
    assert imported_rooms(PACKAGE / "config.py") - {"utils"} <= CONFIG_MAY_IMPORT
    rooms = {p.name for p in PACKAGE.iterdir() if (p / "__init__.py").is_file()}
    assert rooms == set(ALLOWED)


@pytest.mark.parametrize("room", sorted(ALLOWED))
def test_room_imports_only_what_it_may(room):
    for path in sorted((PACKAGE / room).glob("*.py")):
        used = imported_rooms(path) - {room, "utils"}
        assert not used & PROGRAMS, f"{path.name} imports a program: {sorted(used & PROGRAMS)}"
        assert used <= ALLOWED[room], f"roto_trl/{room}/{path.name} imports {sorted(used - ALLOWED[room])}"


def test_importing_the_package_loads_neither_torch_nor_mujoco():
    import subprocess
    import sys

    code = "import sys, roto_trl; print(sorted({m.split('.')[0] for m in sys.modules} & {'torch', 'mujoco'}))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
