"""The house's shape: the layers docs/architecture.md draws (read from its picture, so the doc
and this test cannot disagree) are the import rules. The folders of epoet/ (and the modules at
its top, each a node of its own), analysis/ and pipeline/ form a graph with no cycle, and no node
imports one on its own line of the picture or above it. Every module stays under MAX_LINES, and
modules import each other in no circle.

Each package's schema module, `epoet/<package>/config.py`, is a node of its own: composition
imports the schemas (the registry imports the algorithms' records there), never the code beside
them, so the schemas sit low and their packages high.

Imports are read from the source (ast): module-level ones, those under `if`/`try`/`with` included,
those under `if TYPE_CHECKING:` (a type-only import still says that one module leans on another)
and those inside functions (deferred on purpose: optional extras, heavy imports; a deferred
import still makes its module lean on the other, so it counts for every rule). One kind is held
apart: a schema module's import of its own package's code inside a function (an algorithm's
`runner`, its `check_inputs`), the link a record gives from the settings to the code they run;
it is a runtime lookup, the dotted strings it replaced, and `RUNNER_LINKS` checks its form.
"""

from __future__ import annotations

import ast
import re
import subprocess
import sys
from itertools import takewhile
from pathlib import Path

import pytest

from epoet.registry import DECLARED, algorithms

ROOT = Path(__file__).resolve().parent.parent
MAX_LINES = 400
PICTURE = ROOT / "docs" / "architecture.md"
PICTURE_SECTION = "## The layers"
# a folder (`envs/`), its schema module (`envs/config.py`) or a top-level module (`run.py`)
NODE = re.compile(r"<?\w+>?/(config\.py)?|\w+\.py")
NEW_ALGORITHM = "<algorithm>/"  # the picture's place for an algorithm it does not name
SCHEMA = re.compile(r"epoet\.(\w+)\.config")

# The packages of the algorithms, from their records (an algorithm's schema module and its
# code live in one package).
ALGORITHM_PACKAGES = {r.schema.__module__.split(".")[1] + "/" for r in algorithms()}


def _module(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {
    _module(p): p
    for d in ("epoet", "analysis", "pipeline")
    for p in sorted((ROOT / d).rglob("*.py"))
}


def _imported(node: ast.AST) -> set[str]:
    """The project modules one import statement names."""
    if isinstance(node, ast.Import):
        return {a.name for a in node.names if a.name in MODULES}
    if isinstance(node, ast.ImportFrom) and node.module and not node.level:
        names = (node.module, *(f"{node.module}.{a.name}" for a in node.names))
        return {name for name in names if name in MODULES}
    return set()


def _is_runner_link(module: str, other: str, deferred: bool) -> bool:
    """A schema module's import of its own package's code, inside a function."""
    match = SCHEMA.fullmatch(module)
    return deferred and match is not None and other.startswith(f"epoet.{match.group(1)}.")


def _imports(module: str, path: Path) -> tuple[set[str], set[str]]:
    """The project modules `path` imports, anywhere in it (type-only and deferred ones
    included), and apart from them its runner links."""
    tree = ast.parse(path.read_text())
    in_functions = {
        id(node)
        for func in ast.walk(tree)
        if isinstance(func, (ast.FunctionDef, ast.AsyncFunctionDef))
        for node in ast.walk(func)
    }
    found: set[str] = set()
    links: set[str] = set()
    for node in ast.walk(tree):
        for other in _imported(node):
            deferred = id(node) in in_functions
            (links if _is_runner_link(module, other, deferred) else found).add(other)
    return found, links


_READ = {m: _imports(m, p) for m, p in MODULES.items()}
IMPORTS = {m: imports for m, (imports, _) in _READ.items()}
RUNNER_LINKS = {m: links for m, (_, links) in _READ.items() if links}


def _node(module: str) -> str:
    """The folder, schema module or top-level module of the picture that `module` belongs to."""
    top, *rest = module.split(".")
    if top != "epoet":
        return f"{top}/"
    if not rest:
        return "__init__.py"
    if SCHEMA.fullmatch(module):
        return f"{rest[0]}/config.py"
    return f"{rest[0]}/" if (ROOT / "epoet" / rest[0]).is_dir() else f"{rest[0]}.py"


def _algorithm_package(node: str) -> str | None:
    """The algorithm package `node` is, or is the schema module of; None for any other node."""
    package = node.removesuffix("config.py")
    return package if package in ALGORITHM_PACKAGES else None


def _placeholder(node: str) -> str:
    """Where the picture draws `node` if it does not name it: an algorithm's package on the
    `<algorithm>/` line, its schema module on the `<algorithm>/config.py` line."""
    if _algorithm_package(node) is None:
        return node
    return NEW_ALGORITHM + ("config.py" if node.endswith("config.py") else "")


def _drawn_layers() -> list[list[str]]:
    """The picture's layers, lowest first: each line's leading node names, in the first code
    block after PICTURE_SECTION."""
    section = PICTURE.read_text(encoding="utf-8").split(PICTURE_SECTION, 1)[1]
    block = section.split("```", 2)[1]
    lines = [list(takewhile(NODE.fullmatch, line.split())) for line in block.splitlines()]
    return [names for names in reversed(lines) if names]


LAYERS = _drawn_layers()
NODES = sorted({_node(m) for m in MODULES})


def _level(node: str) -> int:
    """The line of the picture `node` is on, counted from the bottom."""
    for level, names in enumerate(LAYERS):
        if node in names:
            return level
    for level, names in enumerate(LAYERS):
        if _placeholder(node) in names:
            return level
    raise AssertionError(f"{node} is on no line of {PICTURE.name}'s picture: draw it")


def _folder_graph() -> dict[str, dict[str, list[str]]]:
    """node -> the nodes it imports -> the module imports that make the arrow."""
    graph: dict[str, dict[str, list[str]]] = {n: {} for n in NODES}
    for module, imported in IMPORTS.items():
        for other in sorted(imported):
            if _node(other) != _node(module):
                graph[_node(module)].setdefault(_node(other), []).append(f"{module} -> {other}")
    return graph


def _cycle(graph: dict[str, set[str]] | dict[str, dict[str, list[str]]]) -> list[str] | None:
    """One cycle of `graph` (its nodes in order, the first repeated at the end), or None."""
    done: set[str] = set()

    def walk(node: str, path: list[str]) -> list[str] | None:
        if node in path:
            return path[path.index(node) :] + [node]
        if node in done:
            return None
        for after in sorted(graph[node]):
            if (found := walk(after, path + [node])) is not None:
                return found
        done.add(node)
        return None

    return next((c for n in sorted(graph) if (c := walk(n, [])) is not None), None)


@pytest.mark.parametrize("module", sorted(MODULES))
def test_no_module_is_over_the_line_cap(module: str) -> None:
    lines = len(MODULES[module].read_text().splitlines())
    assert lines <= MAX_LINES, f"{module} has {lines} lines"


def test_no_module_import_cycle() -> None:
    cycle = _cycle(IMPORTS)
    assert cycle is None, "import cycle: " + " -> ".join(cycle or [])


def test_the_picture_draws_every_folder_once() -> None:
    drawn = [name for names in LAYERS for name in names if not name.startswith(NEW_ALGORITHM)]
    assert len(drawn) == len(set(drawn)), f"drawn twice: {sorted(drawn)}"
    unnamed_algorithms = {n for n in NODES if _algorithm_package(n)} - set(drawn)
    assert set(drawn) == set(NODES) - unnamed_algorithms, (
        f"drawn but not in the code: {sorted(set(drawn) - set(NODES))}; "
        f"in the code but not drawn: {sorted(set(NODES) - set(drawn) - unnamed_algorithms)}"
    )


def test_the_folder_graph_has_no_cycle() -> None:
    graph = _folder_graph()
    cycle = _cycle(graph)
    assert cycle is None, "folder cycle: " + "; ".join(
        graph[a][b][0] for a, b in zip(cycle or [], (cycle or [])[1:])
    )


def test_no_folder_imports_one_above_it_or_beside_it() -> None:
    against = [
        f"{node} (line {_level(node)}) imports {other} (line {_level(other)}): {', '.join(why)}"
        for node, arrows in _folder_graph().items()
        for other, why in arrows.items()
        if _level(other) >= _level(node)
    ]
    assert not against, "\n".join(against)


def _floors() -> dict[str, int]:
    """Each node's floor of the folder graph: one above the highest node it imports, 0 for a
    node that imports none (its longest import path down)."""
    graph, floors = _folder_graph(), {}

    def floor(node: str) -> int:
        if node not in floors:
            floors[node] = 1 + max((floor(o) for o in graph[node]), default=-1)
        return floors[node]

    for node in graph:
        floor(node)
    return floors


def test_each_line_of_the_picture_is_a_floor_of_the_import_graph() -> None:
    """Every node the picture names is drawn on its floor, and there are as many lines as
    floors; an algorithm it does not name (`<algorithm>/`) only obeys the import rule above."""
    floors = _floors()
    drawn = {name: level for level, names in enumerate(LAYERS) for name in names}
    misplaced = [
        f"{node} is drawn on line {drawn[node]} but its floor is {floor}"
        for node, floor in sorted(floors.items())
        if node in drawn and drawn[node] != floor
    ]
    assert not misplaced, "\n".join(misplaced)
    assert len(LAYERS) == max(floors.values()) + 1


def _with_parents(module: str) -> set[str]:
    """`module` and the packages Python runs before it (epoet.open_ended for
    epoet.open_ended.config)."""
    parts = module.split(".")
    return {".".join(parts[:i]) for i in range(1, len(parts) + 1)} & set(MODULES)


def test_the_registry_names_each_record_and_each_record_its_runner() -> None:
    """epoet/registry.py imports each record from its schema module, an import static tools
    follow; each of those modules links to its own package's code by function-level imports
    only (its `runner`), so it sits below the config and its package above."""
    for record in DECLARED:
        module = record.schema.__module__
        assert module in IMPORTS["epoet.registry"], f"registry.py does not import {module}"
        assert RUNNER_LINKS.get(module), f"{module}'s record names no runner by an import"
        assert _level(_node(module)) < _level("registry.py") < _level("config.py")
        assert _level(_node(module)) < _level(_node(next(iter(RUNNER_LINKS[module]))))
    assert set(RUNNER_LINKS) <= {r.schema.__module__ for r in DECLARED} | {
        m for m in MODULES if SCHEMA.fullmatch(m)
    }


def test_composing_and_help_import_no_torch_mujoco_or_renderer() -> None:
    """The schemas the registry imports keep composition and `--help` light: neither imports
    torch or MuJoCo (a schema module that imported its algorithm's code at module level
    would), nor the terrain renderers' numba and scipy.ndimage (the kind's module checks
    `terrain.kind`). One fresh interpreter composes every algorithm's config, then prints
    `--help`."""
    script = (
        "import runpy, sys\nfrom epoet.config import compose, validate\n"
        "from epoet.registry import names\n"
        "for algo in names():\n"
        "    validate(compose([f'algo={algo}']))\n"
        "sys.argv = ['epoet', '--help']\n"
        "try:\n    runpy.run_module('epoet', run_name='__main__')\n"
        "except SystemExit as end:\n    assert not end.code, end.code\n"
        "heavy = ('torch', 'torchrl', 'mujoco', 'numba', 'scipy.ndimage')\n"
        "imported = [m for m in heavy if m in sys.modules]\n"
        "assert not imported, imported\n"
    )
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "algo=" in done.stdout  # the help was printed


def test_the_rules_see_what_they_check() -> None:
    """Deferred and TYPE_CHECKING imports are both read (and count for every rule); the picture
    orders the folders as the data flows; and the rules would fail on the arrows that once ran
    against it."""
    assert "epoet.rollout.backends.ray_host" in IMPORTS["epoet.rollout.evaluators"]  # deferred
    assert "epoet.tracking" in IMPORTS["epoet.run_state"]  # type-only
    assert RUNNER_LINKS["epoet.ppo.config"] == {"epoet.ppo.train"}  # held apart, not dropped
    assert "epoet.ppo.train" not in IMPORTS["epoet.ppo.config"]
    assert "epoet.ppo.config" in IMPORTS["epoet.ppo.train"]
    # the steps of the loop do not call back into it (no mixin, no `self: Epoet`)
    for step in (
        "epoet.open_ended.reproduction",
        "epoet.open_ended.transfer",
        "epoet.open_ended.service",
    ):
        assert "epoet.open_ended.loop" not in IMPORTS[step], step
    flow = [
        "pipeline/",
        "run.py",
        "open_ended/",
        "config.py",
        "es/",
        "rollout/",
        "envs/",
        "terrain/",
    ]
    assert [_level(n) for n in flow] == sorted((_level(n) for n in flow), reverse=True)
    assert _level("core/") == 0 < min(_level(n) for n in NODES if n not in ("core/", "__init__.py"))
    assert _level("epoet_sac/") > _level("open_ended/") == _level("rl/") == _level("eval/")
    assert _cycle({"config.py": {"eval/"}, "eval/": {"cli.py"}, "cli.py": {"config.py"}})


def test_epoet_knows_nothing_of_the_loop_that_extends_it() -> None:
    """ePOET-SAC's loop extends ePOET's (a subclass with its own steps, keys and metrics): no
    module of epoet/open_ended/ imports ePOET-SAC's or names it."""
    leaning = [
        f"{m}: {sorted(i for i in IMPORTS[m] if i.startswith('epoet.epoet_sac'))}"
        for m, p in MODULES.items()
        if m.startswith("epoet.open_ended")
        and (
            any(i.startswith("epoet.epoet_sac") for i in IMPORTS[m])
            or re.search(r"epoet[_-]?sac", p.read_text(), re.IGNORECASE)
        )
    ]
    assert not leaning, "\n".join(leaning)
