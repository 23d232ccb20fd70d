"""The house's shape (docs/architecture.md): every module of epoet/, analysis/ and pipeline/
under MAX_LINES lines, no import cycle, and no import from a lower wing to a higher one, so data
flows one way: config -> run -> algorithm -> rollout -> envs/terrain, with tracking and core beside
and `core` the ground floor, importing nothing else of the package.

Imports are read from the source (ast): module-level ones, those under `if`/`try`/`with` included,
those under `if TYPE_CHECKING:` (a type-only circle or upward import still says that one module
leans on another) and those inside functions (deferred on purpose: optional extras, heavy
imports; a deferred import still makes its module lean on the other, so it counts for cycles and
for the wing rule alike).
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from epoet.registry import algorithms

ROOT = Path(__file__).resolve().parent.parent
MAX_LINES = 400

# The packages of the algorithms, from their records (an algorithm's runner lives in its
# package, epoet.<package>.<module>.train): a new algorithm's folder joins the algorithms wing,
# and its config.py the schemas wing, without an edit here.
ALGORITHM_PACKAGES = tuple(sorted({".".join(r.runner.split(".")[:2]) for r in algorithms()}))

# Lowest first; a module may import its own wing and the wings before it.
WINGS: list[tuple[str, tuple[str, ...]]] = [
    ("core", ("epoet.core",)),
    (
        "schemas",
        (
            "epoet.envs.config",
            "epoet.terrain.config",
            "epoet.es.config",
            *(f"{package}.config" for package in ALGORITHM_PACKAGES),
            "epoet.tracking.config",
            "epoet.eval.config",
        ),
    ),
    ("config", ("epoet.config", "epoet.registry", "epoet.cli")),
    ("tracking", ("epoet.tracking",)),
    ("run state", ("epoet.run_state",)),
    ("terrain", ("epoet.terrain",)),
    ("envs", ("epoet.envs",)),
    ("rollout", ("epoet.rollout",)),
    ("algorithms", ("epoet.es", *ALGORITHM_PACKAGES)),
    ("eval", ("epoet.eval",)),
    ("commands", ("epoet.run", "epoet.sweep", "epoet.__main__", "epoet")),
    ("analysis", ("analysis",)),
    ("pipeline", ("pipeline",)),
]


def _module(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {
    _module(p): p
    for d in ("epoet", "analysis", "pipeline")
    for p in sorted((ROOT / d).rglob("*.py"))
}


def _wing(module: str) -> int:
    """The index of the most specific wing prefix that names `module`."""
    best = (-1, -1)
    for level, (_, prefixes) in enumerate(WINGS):
        for prefix in prefixes:
            if module == prefix or module.startswith(prefix + "."):
                best = max(best, (len(prefix), level))
    assert best[1] >= 0, f"{module} belongs to no wing: add it to WINGS"
    return best[1]


def _imports(path: Path) -> set[str]:
    """The project modules `path` imports, anywhere in it (type-only and deferred ones
    included)."""
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names if a.name in MODULES)
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            found.update(
                name
                for name in (node.module, *(f"{node.module}.{a.name}" for a in node.names))
                if name in MODULES
            )
    return found


@pytest.mark.parametrize("module", sorted(MODULES))
def test_no_module_is_over_the_line_cap(module: str) -> None:
    lines = len(MODULES[module].read_text().splitlines())
    assert lines <= MAX_LINES, f"{module} has {lines} lines"


def test_no_import_cycle() -> None:
    graph = {m: _imports(p) for m, p in MODULES.items()}
    done: set[str] = set()

    def walk(module: str, path: list[str]) -> None:
        if module in path:
            pytest.fail("import cycle: " + " -> ".join(path[path.index(module) :] + [module]))
        if module in done:
            return
        for imported in sorted(graph[module]):
            walk(imported, path + [module])
        done.add(module)

    for module in sorted(graph):
        walk(module, [])


def test_core_imports_nothing_else_of_the_package() -> None:
    """The ground floor: run-level code (checkpointing a run, reporting its stop) lives above it,
    in epoet/run_state.py, and test helpers in tests/."""
    outside = [
        f"{m} imports {i}"
        for m, p in MODULES.items()
        if _wing(m) == 0
        for i in sorted(_imports(p))
        if _wing(i) != 0
    ]
    assert not outside, "\n".join(outside)


def test_no_wing_imports_a_higher_one() -> None:
    upward = [
        f"{m} ({WINGS[_wing(m)][0]}) imports {i} ({WINGS[_wing(i)][0]})"
        for m, p in MODULES.items()
        for i in sorted(_imports(p))
        if _wing(i) > _wing(m)
    ]
    assert not upward, "\n".join(upward)


def test_the_rules_see_what_they_check() -> None:
    """Deferred and TYPE_CHECKING imports are both read (and count for both rules); and the
    wings order the modules as the data flows."""
    evaluators = MODULES["epoet.rollout.evaluators"]  # Ray's backend is imported on demand
    assert "epoet.rollout.backends.ray_cluster" in _imports(evaluators)
    assert "epoet.tracking" in _imports(MODULES["epoet.run_state"])  # type-only
    # the steps of the loop do not call back into it (no mixin, no `self: EPOET`)
    for step in ("epoet.poet.reproduction", "epoet.poet.transfer", "epoet.poet.service"):
        assert "epoet.poet.loop" not in _imports(MODULES[step]), step
    assert _wing("epoet.core.schema") == 0 < _wing("epoet.poet.config")
    assert _wing("epoet.run") > _wing("epoet.poet.loop") > _wing("epoet.rollout.engine")
    assert _wing("epoet.rollout.engine") > _wing("epoet.envs.model") > _wing("epoet.config")


def test_epoet_knows_nothing_of_the_loop_that_extends_it() -> None:
    """ePOET-SAC's loop extends ePOET's (a subclass with its own steps, keys and metrics): no
    module of epoet/poet/ imports ePOET-SAC's or names it."""
    leaning = [
        f"{m}: {sorted(i for i in _imports(p) if i.startswith('epoet.epoet_sac'))}"
        for m, p in MODULES.items()
        if m.startswith("epoet.poet")
        and (
            any(i.startswith("epoet.epoet_sac") for i in _imports(p))
            or "sac" in p.read_text().lower()
        )
    ]
    assert not leaning, "\n".join(leaning)
