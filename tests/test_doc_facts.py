"""Facts the documentation states that the code also holds, checked against their source: the
composed config (what `python -m epoet ... --cfg job --resolve` prints), the shipped suite, the
Makefile and the commands' `--help`; and every command and run option the pages show exists. A
change that makes a page wrong fails here, naming the page; the fix is the page (or, if the page
was right, the change)."""

from __future__ import annotations

import importlib.util
import itertools
import json
import os
import re
import shlex
import subprocess
from functools import cache
from pathlib import Path
from typing import Any

import pytest
from omegaconf import OmegaConf

from epoet.cli import RUN_GROUPS
from epoet.config import compose, load
from epoet.core.algorithm import Family
from epoet.eval.suite import load_suite
from epoet.eval.suite_format import LEVEL_BOUNDS, LEVELS, level_of
from epoet.registry import names
from test_help import PACKAGES, entry_points, run

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


def table_rows(text: str) -> list[list[str]]:
    """The cells of every Markdown table row of `text`, in order."""
    return [
        [cell.strip() for cell in line.strip().strip("|").split("|")]
        for line in text.splitlines()
        if line.startswith("|")
    ]


def table_row(name: str, first_cell: str) -> list[str]:
    """The cells of the table row of a page whose first cell is `first_cell`."""
    for cells in table_rows((DOCS / name).read_text(encoding="utf-8")):
        if cells[0] == first_cell:
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


# What each timed command's time depends on: `make train` runs the main job (the package, the
# laptop budget and every config it composes), `make test` the tests; both the Makefile.
TIMED = {"train": ("epoet", "conf", "Makefile"), "test": ("tests", "Makefile")}
REMAKING = "EPOET_MAKE_TIMES"  # set by bench/make_times.py in the clone it times


def git(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True)


@pytest.mark.parametrize("target", sorted(TIMED))
def test_the_timing_record_is_newer_than_a_change_to_what_it_timed(target: str) -> None:
    """The README's time of `make <target>` was measured at or after the last commit that
    changed what it times: a change to those files asks for `python bench/make_times.py`."""
    if os.environ.get(REMAKING):
        pytest.skip("bench/make_times.py is timing this very commit: the record comes after")
    if git("rev-parse", "--is-shallow-repository").stdout.strip() != "false":
        pytest.skip("needs the repository's history (a full git clone)")
    measured = timing_record()[target]["commit"]
    last = git("log", "-1", "--format=%H", "HEAD", "--", *TIMED[target]).stdout.strip()
    newer = git("merge-base", "--is-ancestor", last, measured).returncode == 0
    assert newer, (
        f"`make {target}` was timed at {measured[:7]}, before {last[:7]} changed "
        f"{', '.join(TIMED[target])}: run python bench/make_times.py --targets {target}"
    )


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


# --- configs.md's budget table, the rendering and selection defaults, the shipped suite ------

BUDGETS = (*SMALLER_BUDGETS, "paper")
BASELINES = tuple(names(Family.BASELINE))
OPEN_ENDED = tuple(names(Family.OPEN_ENDED))


def quantity(text: str) -> float:
    """A count as the tables write it: 400, 100k, 6M, 1.024M."""
    match = re.fullmatch(r"([\d.]+)([kM]?)", text.strip())
    assert match, f"not a count: {text!r}"
    return float(match.group(1)) * {"": 1, "k": 1e3, "M": 1e6}[match.group(2)]


def hours(value: float, clock: str) -> str:
    return f"{value:g} {clock} hour{'' if value == 1 else 's'}"


@pytest.mark.parametrize("name", BUDGETS)
def test_the_budget_table_is_the_composed_configs(name: str) -> None:
    """configs.md's row of each budget, cell by cell (by the header's names), against the
    config ePOET composes on it, and the baselines' frames against theirs."""
    row = dict(zip(table_row("configs.md", "budget"), table_row("configs.md", f"`{name}`")))
    cfg = composed("algo=epoet", f"budget={name}")
    budget, algo, terrain, agent = cfg["budget"], cfg["algo"], cfg["terrain"], cfg["agent"]
    if budget["cpu_hours"] is not None:
        assert row["stops at"] == hours(budget["cpu_hours"], "CPU")
    elif budget["hours"] is not None:
        assert row["stops at"] == hours(budget["hours"], "wall")
    else:
        assert row["stops at"] == "iterations / frames"
    # "at most": a clock stops the run first (the paper row's 2000 is a bound too, by its own
    # section); the number is what the test holds
    assert row["iterations"].removeprefix("at most ") == str(budget["iterations"])
    assert row["ES pairs (episodes)"] == f"{budget['n_pairs']} ({2 * budget['n_pairs']})"
    assert row["episode steps"] == str(budget["episode_steps"]) == str(agent["max_episode_steps"])
    assert row["eval episodes"] == str(budget["eval_episodes"])
    assert row["thresholds ×"] == f"{budget['score_scale']:g}"
    every = algo["iterations_before_transfer"]  # reproduction: adjust_interval of these
    assert row["transfer / reproduce every"] == f"{every} / {every * algo['adjust_interval']}"
    schedule = re.fullmatch(r"(\S+) m, \+(\S+) m", row["S: start, per iteration"])
    assert schedule, row["S: start, per iteration"]
    stated = tuple(float(value) for value in schedule.groups())
    assert stated == (terrain["max_height"], terrain["max_height_step"])
    assert row["integrator"].lower() == agent["integrator"]
    frames = re.fullmatch(r"(?:at most )?(.+) \((\S+)\)", row["baseline frames (eval every)"])
    assert frames, row["baseline frames (eval every)"]
    by_algo = dict(re.findall(r"(PPO|SAC|VMPO) (\S+?)(?:,|$)", frames.group(1)))
    for baseline in BASELINES:  # one count for all, or each by name (the paper's)
        given = by_algo.get(baseline.upper(), frames.group(1))
        limits = composed(f"algo={baseline}", f"budget={name}")["budget"]
        assert limits["frames"] == quantity(given), (name, baseline)
        assert limits["eval_every"] == quantity(frames.group(2)), (name, baseline)


def test_the_budget_particulars_in_configs_are_the_configs() -> None:
    text = page("configs.md")
    sac_frames = ", ".join(
        f"{b} {composed('algo=epoet_sac', f'budget={b}')['algo']['frames_per_iteration']}"
        for b in BUDGETS
    )
    assert f"gradient update): {sac_frames} (" in text
    laptop = {a: composed(f"algo={a}", "budget=laptop") for a in OPEN_ENDED}
    iterations = {a: cfg["budget"]["iterations"] for a, cfg in laptop.items()}
    assert (
        f"On the laptop budget ePOET-SAC runs {iterations['epoet_sac']} iterations (two joins), "
        f"where ePOET runs {iterations['epoet']}" in text
    )
    budget, algo = laptop["epoet"]["budget"], laptop["epoet"]["algo"]
    scale, every = budget["score_scale"], algo["iterations_before_transfer"]
    assert f"Its {budget['episode_steps']}-step agents" in text
    repro = algo["repro_threshold"]
    assert f"threshold, {repro:g} × {scale:g} = {repro * scale:g} of" in text
    criterion = f"[{algo['mc_lower'] * scale:g}, {algo['mc_upper'] * scale:g}]"
    assert f"The minimal criterion {criterion}" in text
    assert f"intervals are shorter ({every} / {every * algo['adjust_interval']})" in text
    # where each budget's height schedule reaches the paper suite's 1 m
    schedule = section("configs.md", "Height schedule")
    terrain = {name: composed(f"budget={name}")["terrain"] for name in BUDGETS}
    start = {name: t["max_height"] for name, t in terrain.items()}
    reached = {
        name: round((1.0 - t["max_height"]) / t["max_height_step"]) for name, t in terrain.items()
    }
    rate = terrain["paper"]["max_height_step"]
    assert (start["workstation"], reached["workstation"]) == (start["paper"], reached["paper"])
    assert f"the workstation and paper budgets from {start['paper']:g} m at the paper's rate " in (
        schedule
    )
    assert f"(1 m at iteration {reached['paper']})" in schedule
    assert terrain["laptop"]["max_height_step"] == rate / 2
    laptop = (
        f"{start['laptop']:g} m (1 m at iteration {reached['laptop']} of {iterations['epoet']})"
    )
    assert "the laptop budget at half the rate" in schedule and f"from {laptop}" in schedule
    assert start["smoke"] == 1.0 and "the smoke budget from 1 m" in schedule


def without_parentheses(text: str) -> str:
    """The text with every parenthesised aside removed, nested ones (links) included."""
    while (shorter := re.sub(r"\([^()]*\)", "", text)) != text:
        text = shorter
    return text


def test_the_rendering_each_budget_trains_on_is_the_configs() -> None:
    """fidelity.md names, per budget, the terrain rendering ePOET and ePOET-SAC train on."""
    ours = without_parentheses(table_row("fidelity.md", "CPPN feature scale")[3])
    stated = {  # "`reference` at the workstation budget and the paper budget, `clean` at ..."
        budget: rendering
        for rendering, budgets in re.findall(r"`(clean|reference)` at the ([^`]*)", ours)
        for budget in re.findall(rf"\b({'|'.join(BUDGETS)})\b", budgets)
    }
    assert sorted(stated) == sorted(BUDGETS), ours
    for algo in OPEN_ENDED:
        for budget in BUDGETS:
            rendering = composed(f"algo={algo}", f"budget={budget}")["terrain"]["rendering"]
            assert rendering == stated[budget], (algo, budget, rendering)


def test_the_selection_defaults_the_docs_name_are_the_configs() -> None:
    """Every run chooses with the root's `selection` but ePOET at the workstation budget, whose
    held-out set is its own size (decided on the validation suite), as the page says."""
    selection = composed()["selection"]
    text = section("evaluation.md", "Which agent a run exports")
    for algo in (*OPEN_ENDED, *BASELINES):
        for budget in BUDGETS:
            own = composed(f"algo={algo}", f"budget={budget}")["selection"]
            differs = {key: value for key, value in own.items() if value != selection[key]}
            if (algo, budget) == ("epoet", "workstation"):
                assert list(differs) == ["terrains"]
                terrains = f"{selection['terrains']} with one episode each (`conf/config.yaml`)"
                ours = f"{differs['terrains']} for ePOET at the workstation budget"
                assert f"How many terrains: {terrains}, and {ours}" in text
            else:
                assert not differs, (algo, budget, differs)
    assert f"`selection.rule` (`{selection['rule']}`, the default, or `own`)" in page("configs.md")
    assert f"`selection.rule={selection['rule']}` (default)" in text
    assert f"`selection.max_height` (the paper suite's {selection['max_height']:g} m)" in text
    assert selection["rendering"] == "reference"
    assert "`selection.rendering` (default the reference's, the paper suite's" in text
    assert selection["episode_ratio"] == load_suite().course.episode_ratio
    assert "as long as the suites' (`selection.episode_ratio`" in text
    episodes = {1: "one", 2: "two"}.get(selection["episodes"], str(selection["episodes"]))
    held_out = f"the default {selection['terrains']} held-out terrains with {episodes} episode"
    assert held_out in page("RESULTS.md")


def test_the_shipped_suite_is_what_the_docs_say() -> None:
    """Its size, rounds, lineages, S per round, levels, names and course, as evaluation.md and
    fidelity.md give them, against epoet/suite/ and the generator's settings (conf/suite.yaml)."""
    suite, generator = load_suite(), OmegaConf.load(ROOT / "conf" / "suite.yaml")
    text = section("evaluation.md", "The shipped suite")
    rounds = sorted({t.info["round"] for t in suite.terrains})
    lineages = sorted({t.info["lineage"] for t in suite.terrains})
    assert len(suite.terrains) == len(rounds) * len(lineages)
    assert (len(rounds), len(lineages)) == (len(generator.max_heights), generator.children)
    assert f"of {len(suite.terrains)} terrains it did not train on" in page("evaluation.md")
    assert f"{len(suite.terrains)} CPPN terrains made by" in text
    assert f"{len(rounds)} reproduction rounds x {len(lineages)} mutated children" in text
    assert f"{len(lineages)} lineages start from one root genome" in text
    heights = [{t.max_height for t in suite.terrains if t.info["round"] == r} for r in rounds]
    assert heights == [{h} for h in generator.max_heights]
    shown = ", ".join(f"{h:g}" for h in generator.max_heights)
    assert f"with S rising round by round ({shown} m)" in text
    assert f"the first of up to {generator.max_tries} mutations" in text
    counts = suite.level_counts()
    assert list(counts) == list(LEVELS)
    levels = ", ".join(f"{counts[level]} {level}" for level in LEVELS[:-1])
    assert f"{levels} and {counts[LEVELS[-1]]} {LEVELS[-1]} terrains" in text
    assert all(t.name == f"r{t.info['round']}l{t.info['lineage']}" for t in suite.terrains)
    assert "named `r<round>l<lineage>`" in text
    assert all(t.level == level_of(t.roughness) for t in suite.terrains)
    bounds = " <= ".join(f"{a} < {b:g}" for a, b in zip(LEVELS, LEVEL_BOUNDS))
    assert f"bucketed as the reference: {bounds} <= {LEVELS[-1]}." in text
    # fidelity.md's relief table: its row is named by the terrains per level
    per_level = set(counts.values())
    assert len(per_level) == 1
    cells = table_row("fidelity.md", f"`shipped` (ours, {per_level.pop()} per level)")
    by_level = {t.level: t.max_height for t in suite.terrains}
    assert cells[1] == ", ".join(f"{by_level[level]:g} m {level}" for level in LEVELS)


def test_the_course_is_the_suites() -> None:
    """evaluation.md's course: where it starts and ends, how long evaluation episodes last, and
    the share a budget with shorter episodes walks (Course.rules, what evaluation runs)."""
    course = load_suite().course
    text = section("evaluation.md", "The course")
    assert f"spawns at x = {course.start_x:g} m" in text
    ahead = course.finish_x - course.start_x
    assert f"finish line is at x = +{course.finish_x:g} m: {ahead:g} m ahead" in text
    assert f"episodes on the suite last {course.episode_ratio:g}x a run's training" in text

    def walk(budget: str) -> tuple[int, str, int]:
        """A budget's training episode steps, and the course it walks in evaluation."""
        agent = load([f"budget={budget}"]).agent
        rules = course.rules(agent)
        length = rules.finish_x - rules.start_x
        return agent.max_episode_steps, f"{length:.2g}", rules.max_episode_steps

    (n, length, steps), (_, smoke, smoke_steps) = walk("laptop"), walk("smoke")
    walked = f"(laptop, {n} steps: {length} m in {steps} steps; smoke: {smoke} m in {smoke_steps})"
    assert walked in text
    assert f"|y| <= {course.half_width:g} m" in page("evaluation.md")


# --- every module and option the pages name ------------------------------------------------

# docs/algorithms/adding.md's worked example: an algorithm the page adds, not one that ships
EXAMPLE_ALGORITHMS = {"docs/algorithms/adding.md": {"toy", "random_search"}}


def doc_pages() -> list[Path]:
    """The README and the documentation's pages; not the records (docs/results/)."""
    return [ROOT / "README.md", *sorted(DOCS.glob("*.md")), *sorted(DOCS.glob("algorithms/*.md"))]


def commands(path: Path) -> list[str]:
    """Every `python -m` command a page shows: a line of a code block (fenced, or indented after
    a blank line; a `\\` continuation joined, a `#` comment cut) or an inline code span of its
    prose (which may wrap across lines, never across paragraphs)."""
    code, prose = [], []
    fenced = in_code = False
    blank = True
    for line in path.read_text(encoding="utf-8").splitlines():
        if line.lstrip().startswith("```"):
            fenced, blank = not fenced, False
            continue
        in_code = fenced or (line.startswith("    ") and (blank or in_code))
        (code if in_code else prose).append("" if in_code and not line.strip() else line)
        blank = not line.strip()
    lines = re.sub(r"\\\n\s*", " ", "\n".join(code)).splitlines()
    shown = [re.split(r"\s#", line)[0] for line in lines]
    for paragraph in re.split(r"\n\s*\n", "\n".join(prose)):
        shown += [" ".join(span.split()) for span in re.findall(r"`([^`]+)`", paragraph)]
    return [
        command for text in shown for command in re.split(r"&&|;", text) if "python -m " in command
    ]


def test_every_module_the_pages_run_exists() -> None:
    """Each `python -m <module>` a page names anywhere (prose and comments too) is one of this
    repository's commands if it is of its packages; any other (the standard library's, an
    installed tool's) is importable."""
    ours, named = set(entry_points()), set()
    for path in doc_pages():
        text = path.read_text(encoding="utf-8")
        for module, template in re.findall(r"python -m ([\w.]*\w)(\.<)?", text):
            if not template:  # `python -m epoet.eval.<command>`
                named.add((path.relative_to(ROOT).as_posix(), module))
    assert {"epoet", "epoet.eval.evaluate", "analysis.tables", "pipeline.paper"} <= {
        module for _, module in named
    }
    wrong = [
        (where, module)
        for where, module in sorted(named)
        if (
            module not in ours
            if module.split(".")[0] in PACKAGES
            else importlib.util.find_spec(module) is None
        )
    ]
    assert not wrong, wrong


def placeholder(value: str) -> bool:
    """`<run folder>`, `...`, `S` (a seed), `A` (an algorithm): a value to fill in."""
    return bool(re.search(r"<|\.\.\.", value)) or bool(re.fullmatch(r"[A-Z]", value))


def has_key(cfg: dict[str, Any], key: str) -> bool:
    node: Any = cfg
    for part in key.split("."):
        if not isinstance(node, dict) or part not in node:
            return False
        node = node[part]
    return True


def test_every_option_the_pages_give_the_run_exists() -> None:
    """Each `key=value` a page gives `python -m epoet` is a config group choice that composes,
    or a key of the config the command composes (for each choice of a sweep's `a,b`).
    Hydra's own `hydra.` keys and `+` additions are Hydra's to check."""
    unknown, checked = [], 0
    for path in doc_pages():
        name = path.relative_to(ROOT).as_posix()
        for command in commands(path):
            match = re.search(r"python -m epoet(?![.\w])(.*)", command)
            if not match:
                continue
            try:
                words = shlex.split(match.group(1))
            except ValueError:  # an unbalanced quote: words as written
                words = match.group(1).split()
            options = [
                w.split("=", 1)
                for w in words
                if "=" in w and not w.startswith(("-", "+", "~", "hydra"))
            ]
            groups = [
                [f"{key}={choice}" for choice in value.split(",")]
                for key, value in options
                if key in RUN_GROUPS
                and not placeholder(value)
                and value not in EXAMPLE_ALGORITHMS.get(name, ())
            ]
            for choices in itertools.product(*groups):
                try:
                    cfg = composed(*choices)
                except Exception as err:  # a choice the group does not have
                    unknown.append((name, command, f"{choices}: {str(err).splitlines()[0]}"))
                    continue
                for key, _ in options:
                    checked += 1
                    if key not in RUN_GROUPS and "<" not in key and not has_key(cfg, key):
                        unknown.append((name, command, key))
    assert checked > 60 and not unknown, (checked, unknown)


FINAL_REPORT = ROOT / "docs" / "results" / "paper-workstation" / "report" / "paper"


def test_the_readmes_results_open_with_the_final_reports_table():
    """The README's results open with the final experiment's Table 1 on the paper suite (issue
    60): each algorithm's mean success over seeds with its 95 % interval, and its levels, are
    the committed report's cells (`python -m analysis.paper_report` writes them), so a rebuilt
    report that moves a number fails here, naming the README."""
    from epoet.registry import algorithm

    report = (FINAL_REPORT / "table1_seeds_paper.md").read_text(encoding="utf-8")
    means = {  # algorithm -> easy, medium, hard, total
        cells[0]: cells[2:]
        for cells in table_rows(report)
        if len(cells) > 1 and cells[1] == "mean [95 % CI]"
    }
    assert sorted(means) == sorted(names())
    results = (ROOT / "README.md").read_text(encoding="utf-8").split("## Results", 1)[1]
    rows = {cells[0]: cells for cells in table_rows(results.split("\n## ", 1)[0])}
    for algo, (easy, medium, hard, total) in means.items():
        label = algorithm(algo).label
        assert label in rows, f"README.md's results table has no row {label!r}"
        levels = " / ".join(cell.split(" [")[0] for cell in (easy, medium, hard))
        assert rows[label][1:3] == [total, levels], f"README.md's row {label!r}"
