"""Facts the documentation states that the code also holds, checked against their source: the
composed config (what `python -m epoet ... --cfg job --resolve` prints), the Makefile and the
commands' `--help`. A change that makes a page wrong fails here, naming the page; the fix is
the page (or, if the page was right, the change)."""

from __future__ import annotations

import json
import re
from functools import cache
from pathlib import Path
from typing import Any

import pytest
from omegaconf import OmegaConf

from epoet.config import compose
from epoet.registry import names
from test_help import run

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"
SMALLER_BUDGETS = ("smoke", "laptop", "workstation")


def page(name: str) -> str:
    """A documentation page's text with its lines joined, so a phrase may wrap."""
    path = ROOT / name if name == "README.md" else DOCS / name
    return " ".join(path.read_text(encoding="utf-8").split())


def section(name: str, heading: str) -> str:
    """The text of a page's section, from its heading to the next heading of any level."""
    text = (DOCS / name).read_text(encoding="utf-8")
    match = re.search(rf"^#+ {re.escape(heading)}\n(.*?)(?=^#+ |\Z)", text, re.M | re.S)
    assert match, f"docs/{name} has no section {heading!r}"
    return " ".join(match.group(1).split())


def table_row(name: str, first_cell: str) -> list[str]:
    """The cells of the table row of a page whose first cell is `first_cell`."""
    for line in (DOCS / name).read_text(encoding="utf-8").splitlines():
        cells = [cell.strip() for cell in line.strip().strip("|").split("|")]
        if line.startswith("|") and cells[0] == first_cell:
            return cells
    raise AssertionError(f"docs/{name} has no table row {first_cell!r}")


@cache
def composed(*overrides: str) -> Any:
    """The resolved config of `python -m epoet <overrides>`, as plain containers."""
    return OmegaConf.to_container(compose(list(overrides)), resolve=True)


def test_fidelity_says_where_epoet_sac_starts_on_every_budget() -> None:
    paper, _, ours, *_ = table_row("fidelity.md", "ePOET-SAC pre-training and mapping")[1:]
    algo = composed("algo=epoet_sac", "budget=paper")["algo"]
    assert f"{algo['pretrain_iterations']} pre-training iterations" in paper
    assert algo["mapping"] == "random" and "random parameter selection" in paper
    assert algo["sac_init"] is None and "the paper's at `budget=paper`" in ours
    for budget in SMALLER_BUDGETS:
        algo = composed("algo=epoet_sac", f"budget={budget}")["algo"]
        assert algo["pretrain_iterations"] == 0 and "no pre-training" in ours, budget
        assert f"the `{algo['mapping']}` mapping" in ours, budget
        assert f"`algo.sac_init={algo['sac_init']}`" in ours, budget
        assert algo["sac_init"] is None and "SAC starts cold at every budget" in ours
    assert "head start to ask for (`algo.sac_init=reference:sac/42`)" in ours


def test_the_equal_compute_comparison_says_epoet_sac_started_from_the_authors_actor() -> None:
    assert composed("algo=epoet_sac", "budget=workstation")["algo"]["sac_init"] is None
    text = section("RESULTS.md", "ePOET-SAC against ePOET at this budget: 3 seeds")
    assert "default start at this budget then, which these runs kept, is the authors'" in text
    assert "`algo.sac_init=reference:sac/42`, a head start: the default is cold" in text
    assert "no CPU budget here counts" in text


def test_the_workstation_budget_facts_are_the_configs() -> None:
    budget = composed("budget=workstation")["budget"]
    assert f"stops after {budget['cpu_hours']:g} CPU hour" in page("fidelity.md")
    bench = table_row("benchmarks.md", "`bench/time_to_walker.py [--seeds 1,2,3] [override ...]`")
    assert f"`budget.iterations` ({budget['iterations']} at the workstation budget" in bench[1]


def test_the_evaluation_protocol_of_each_budget_is_the_configs() -> None:
    """The end-of-run evaluation's episodes per terrain, by budget, against the paper's 5 and
    `evaluate`'s default."""
    text = page("evaluation.md")
    evaluate = OmegaConf.load(ROOT / "conf" / "evaluate.yaml")
    assert evaluate.episodes == 5 and "as `evaluate` does by default (`episodes=5`)" in text
    by_budget = {
        b: composed(f"budget={b}")["budget"]["eval_episodes"] for b in (*SMALLER_BUDGETS, "paper")
    }
    stated = "; ".join(f"{n} at `{b}`" for b, n in by_budget.items())
    assert f"`budget.eval_episodes` episodes per terrain ({stated})" in text


def help_groups() -> dict[str, set[str]]:
    """Each config group `python -m epoet --help` lists, with its choices."""
    text = run("epoet", "--help").stdout
    return {g: set(o.split("|")) for g, o in re.findall(r"^  ([\w/]+)=([\w|]+)", text, re.M)}


def test_the_config_groups_table_lists_the_choices_help_lists() -> None:
    groups = help_groups()
    assert "hydra/launcher" in groups and "algo" in groups
    for group, choices in groups.items():
        cell = table_row("configs.md", f"`{group}`")[1]
        listed = set(re.findall(r"`(\w+)`", re.sub(r"\([^)]*\)", "", cell)))
        assert listed == choices, (group, listed, choices)


def makefile_variables() -> dict[str, set[str]]:
    """Each Makefile target's user variables (those set with `?=`) that its recipe reads."""
    text = (ROOT / "Makefile").read_text()
    variables = set(re.findall(r"^([A-Z_]+)\s*\?=", text, re.M))
    recipes: dict[str, set[str]] = {}
    for target, recipe in re.findall(r"^([\w-]+):[^\n=]*\n((?:\t.*\n?)*)", text, re.M):
        recipes[target] = set(re.findall(r"\$\(([A-Z_]+)\)", recipe)) & variables
    return recipes


def make_lines() -> list[tuple[str, str, str]]:
    """(page, target, the rest) of every `make <target> ...` command line in the docs."""
    pages = [ROOT / "README.md", *sorted(DOCS.rglob("*.md"))]
    return [
        (path.relative_to(ROOT).as_posix(), target, rest)
        for path in pages
        for target, rest in re.findall(r"^\s+make ([\w-]+)(.*)$", path.read_text(), re.M)
    ]


def test_make_commands_in_the_docs_set_only_what_their_recipe_reads() -> None:
    """Every `make X VAR=...` names variables the recipe of X reads; a synopsis line (one with
    `[optional]` parts and no comment) names all of them."""
    recipes = makefile_variables()
    assert recipes["figures"] >= {"RECORDS", "SUITE", "EXPERIMENT"}
    synopses = 0
    for name, target, rest in make_lines():
        assert target in recipes, (name, target)
        command = rest.split("#")[0]
        named = set(re.findall(r"\b([A-Z][A-Z_]+)=", command))
        assert named <= recipes[target], (name, target, named - recipes[target])
        if "[" in command and command == rest:
            synopses += 1
            assert named == recipes[target], (name, target, recipes[target] - named)
    assert synopses >= 4  # tables, figures, paper, epoet-sac-starts


def out_default(module: str, capsys: pytest.CaptureFixture[str]) -> str:
    """The `--out` default a flag command's `--help` states."""
    main = __import__(module, fromlist=["main"]).main
    with pytest.raises(SystemExit):
        main(["--help"])
    text = " ".join(capsys.readouterr().out.split())
    match = re.search(r"--out OUT .*?\(default: (\S+)\)", text)
    assert match, module
    return match.group(1)


def test_the_output_folders_in_the_docs_are_the_commands_defaults(capsys) -> None:
    figures = section("analysis.md", "`make figures`")
    tables = section("analysis.md", "`make tables`")
    store = out_default("analysis.figures", capsys)
    assert out_default("analysis.tables", capsys) == store
    assert f"writes to `{store}/<input>/<suite name>/`" in figures
    assert f"writes to `{store}/<input>/<suite name>/`" in tables
    records = out_default("analysis.success_vs_compute", capsys)
    assert f"[--out {records}]" in figures and f"into `{records}/<name>/<suite name>/`" in figures


def timing_record() -> dict[str, Any]:
    """bench/make_times.json: what bench/make_times.py measured of `make train` and `make test`."""
    return json.loads((ROOT / "bench" / "make_times.json").read_text(encoding="utf-8"))


def stated_time(entry: dict[str, Any]) -> str:
    """How the docs cite one timed command: its minutes, then the record's commit and date."""
    minutes, seconds = divmod(round(entry["wall_s"]), 60)
    return (
        f"took {minutes} min {seconds:02d} s (commit {entry['commit'][:7]}, "
        f"{entry['date'][:10]}, mean load {entry['load1']['mean']:.1f})"
    )


def test_the_times_of_the_two_commands_are_the_timing_records() -> None:
    """README and the test page give `make train`'s and `make test`'s time, and when the main
    job's loop first shows, as the timing record has them; the record's commands succeeded."""
    record = timing_record()
    train, test = record["train"], record["test"]
    assert train["exit_code"] == 0 and test["exit_code"] == 0
    loop = train["milestones_s"]
    assert all(loop.values()), f"the timed `make train` never showed the loop: {loop}"
    readme = page("README.md")
    assert f"`make train` {stated_time(train)}" in readme
    assert f"`make test` {stated_time(test)}" in readme
    shown = (
        f"admitted its first child after {loop['first_admission']:.0f} s, had ANNECS above 1 "
        f"after {loop['annecs_above_1']:.0f} s and transferred first after "
        f"{loop['first_transfer']:.0f} s"
    )
    assert shown in readme
    assert f"`make test` {stated_time(test)}" in page("getting-started.md")
    last = [line for line in train["tail"] if "[epoet] it " in line][-1]
    pairs, annecs = (re.search(rf"\b{key}=(\d+)", last).group(1) for key in ("pairs", "annecs"))
    assert f"(`pairs={pairs} ... annecs={annecs}`)" in readme
    assert any("done after" in line and "of the shipped suite" in line for line in train["tail"])


def test_the_test_files_the_docs_name_exist() -> None:
    """A renamed test file leaves no page naming the old one (getting-started named
    tests/test_poet.py after it became tests/test_epoet.py)."""
    pages = [ROOT / "README.md", *DOCS.glob("*.md"), *DOCS.glob("algorithms/*.md")]
    named = {
        (path.name, name)
        for path in pages
        for name in re.findall(r"tests/(test_\w+\.py)", path.read_text(encoding="utf-8"))
    }
    assert named
    assert not [(p, n) for p, n in named if not (ROOT / "tests" / n).exists()]


CHOICES = ("algo", "budget", "agent", "terrain", "workers", "tracking")  # config groups


def _doc_pages() -> list[Path]:
    """The README and the documentation's pages (not the committed records)."""
    return [ROOT / "README.md", *sorted(DOCS.glob("*.md")), *sorted(DOCS.glob("algorithms/*.md"))]


def test_every_module_the_docs_run_exists() -> None:
    """Each `python -m <module>` of this repository's packages that a page shows imports."""
    import importlib.util

    named = {
        (path.name, module)
        for path in _doc_pages()
        for module in re.findall(
            r"python -m ((?:epoet|analysis|pipeline)(?:\.\w+)*)", path.read_text()
        )
    }
    assert len(named) > 20  # the pages do name their commands
    missing = [(page_, m) for page_, m in sorted(named) if importlib.util.find_spec(m) is None]
    assert not missing, missing


def test_every_training_option_the_docs_show_exists() -> None:
    """Each `key=value` a page gives `python -m epoet` (one line of a command) is a key of the
    composed config of the algorithm and budget on that line."""
    unknown, checked = [], 0
    for path in _doc_pages():
        for line in re.findall(r"python -m epoet (?!\.)([^`\n|]*)", path.read_text()):
            words = [w for w in line.split() if "=" in w and not w.startswith(("hydra", "+"))]
            if any(re.search(r"<|\.\.\.|\{|=[A-Z]\b", w) for w in words):
                continue  # a placeholder (<kind>, seed=S), not an option
            chosen = [w.split(",")[0] for w in words if w.split("=")[0] in CHOICES]
            if any(w.startswith("algo=") and w[5:] not in names() for w in chosen):
                continue  # docs/algorithms/adding.md's worked example, a sixth algorithm
            cfg = composed(*chosen)
            for word in words:
                checked += 1
                key = word.split("=")[0]
                node: Any = cfg
                for part in key.split("."):
                    node = node.get(part) if isinstance(node, dict) else None
                if key not in CHOICES:
                    if node is None and key not in _NULLABLE(cfg):
                        unknown.append((path.name, word))
    assert checked > 30 and not unknown, (checked, unknown)


def _NULLABLE(cfg: dict[str, Any]) -> set[str]:
    """The dotted keys whose value is null in `cfg` (present, so an option, though None)."""
    found: set[str] = set()

    def walk(node: Any, prefix: str) -> None:
        if isinstance(node, dict):
            for k, v in node.items():
                walk(v, f"{prefix}{k}.")
        elif node is None:
            found.add(prefix[:-1])

    walk(cfg, "")
    return found


def test_the_shipped_suites_size_and_levels_are_the_docs() -> None:
    from epoet.eval.suite import load_suite

    counts = load_suite().level_counts()
    assert sum(counts.values()) == 32
    assert (
        f"{counts['easy']} easy, {counts['medium']} medium, {counts['hard']} hard and "
        f"{counts['extreme']} extreme terrains" in page("evaluation.md")
    )
