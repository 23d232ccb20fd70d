"""The evaluation suite: deterministic regeneration of the shipped data, levels, folder checks."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from conftest import authors
from epoet.config import compose, load, validate
from epoet.envs.model import layout
from epoet.envs.task import EpisodeState, HexapodTask
from epoet.envs.terrain_env import TerrainEnv
from epoet.eval import suite as suite_module
from epoet.eval.evaluate import COMMAND as EVALUATE
from epoet.eval.suite import SHIPPED, SuiteError, example_terrain, load_suite
from epoet.eval.suite_format import LEVELS, Course, level_of, quantize
from epoet.eval.suite_generation import differences, generate, write_suite

ROOT = Path(__file__).resolve().parents[1]


def suite_cfg(*overrides: str):
    return validate(compose(list(overrides), config_name="suite"))


def test_regenerating_the_first_two_rounds_matches_the_shipped_suite_bit_for_bit():
    # The whole suite takes about a minute (`python -m epoet.eval.suite check=true`); each
    # (round, lineage) has its own seed key, so two rounds are an exact prefix of four.
    cfg = suite_cfg("max_heights=[0.4,0.9]")
    terrains, entries = generate(cfg)
    assert len(terrains) == 16
    assert differences(SHIPPED, terrains, entries) == []


def test_a_changed_seed_is_detected_as_a_difference():
    terrains, entries = generate(suite_cfg("max_heights=[0.4]", "seed=1"))
    assert differences(SHIPPED, terrains, entries)


def test_shipped_suite_has_32_terrains_with_levels_from_their_course_roughness():
    suite = load_suite()
    assert len(suite.terrains) == 32
    index = json.loads((SHIPPED / "suite.json").read_text())
    for terrain, entry in zip(suite.terrains, index["terrains"]):
        # the stored roughness is the one recomputed from the stored (quantised) heights
        assert terrain.roughness == pytest.approx(entry["roughness"], rel=1e-9)
        assert terrain.level == level_of(terrain.roughness)
    counts = suite.level_counts()
    assert all(counts[level] >= 4 for level in LEVELS), counts
    # S rises round by round, and so does the median roughness
    medians = [
        np.median([t.roughness for t in suite.terrains if t.info["round"] == r]) for r in range(4)
    ]
    assert medians == sorted(medians)


def test_level_buckets_follow_the_reference_thresholds():
    assert [level_of(v) for v in (0.0, 0.00099, 0.001, 0.0099, 0.01, 0.099, 0.1, 5.0)] == [
        "easy",
        "easy",
        "medium",
        "medium",
        "hard",
        "hard",
        "extreme",
        "extreme",
    ]


def test_course_roughness_reads_only_the_strip_the_robot_walks():
    n, size = 200, 40.0
    hm = np.zeros((n, n))
    axis = np.linspace(-size / 2, size / 2, n)
    hm[:, axis < -10] = np.random.default_rng(0).random((n, int((axis < -10).sum())))
    course = Course(-6.0, 6.0, 0.35, 2000, 2.5)
    assert course.roughness(hm, 1.0, size) < 1e-12  # rough ground behind the start only
    hm2 = hm.copy()
    hm2[n // 2, n // 2] = 1.0  # one spike on the course
    assert course.roughness(hm2, 1.0, size) > 0.0
    assert course.roughness(hm2, 2.0, size) == pytest.approx(4 * course.roughness(hm2, 1.0, size))


def test_a_suite_written_by_write_suite_loads_back(tmp_path):
    cfg = suite_cfg("max_heights=[0.4]", "children=2", "max_tries=2")
    terrains, entries = generate(cfg)
    write_suite(tmp_path, terrains, entries, Course.of(cfg.agent, cfg.episode_ratio))
    suite = load_suite(tmp_path)
    assert [t.name for t in suite.terrains] == ["r0l0", "r0l1"]
    assert suite.course == Course(
        cfg.agent.start_x, cfg.agent.finish_x, 0.35, cfg.agent.max_episode_steps, cfg.episode_ratio
    )
    assert np.array_equal(quantize(suite.terrains[0].heightmap), quantize(terrains[0].heightmap))


@pytest.mark.parametrize(
    "damage, message",
    [
        (lambda d: (d / "suite.json").unlink(), "has no suite.json"),
        (lambda d: (d / "heights.npz").unlink(), "has no heights.npz"),
        (lambda d: (d / "suite.json").write_text("{not json"), "is malformed"),
        (lambda d: (d / "suite.json").write_text(json.dumps({"format": "other"})), "is malformed"),
        (
            lambda d: (d / "suite.json").write_text(
                json.dumps(
                    {**json.loads((d / "suite.json").read_text()), "format": "epoet-suite/1"}
                )
            ),
            "epoet-suite/1.*regenerate",
        ),
        (lambda d: np.savez(d / "heights.npz", r0l0=np.zeros((3, 3))), "is malformed"),
    ],
)
def test_a_malformed_suite_folder_is_one_clear_error(tmp_path, damage, message):
    folder = tmp_path / "suite"
    shutil.copytree(SHIPPED, folder)
    damage(folder)
    with pytest.raises(SuiteError, match=message):
        load_suite(folder)


def test_the_course_is_the_references():
    """The reference's finish: hfield column int((x + 17) * 5) past 200 - 5, i.e. x > 22 m with
    the spawn at x = 0, and its heightfield centred 2.7 m ahead of the spawn (so 0.7 m of
    terrain lie beyond the line). Our terrain is centred at the origin."""
    finish_from_spawn = (200 - 5) / 5 - 17
    for course in (load_suite().course, Course.of(load(["budget=paper"]).agent, 2.5)):
        assert course.finish_x - course.start_x == pytest.approx(finish_from_spawn)
        assert course.start_x == pytest.approx(-2.7)
    assert load_suite().course.episode_ratio * 2000 == 5000  # the reference env's limit


def test_the_course_is_part_of_the_fingerprint(tmp_path):
    """A suite with another course (start, finish or time limit) is another suite: runs evaluated
    on the old one are evaluated again (analysis/tables.py compares fingerprints)."""
    folder = tmp_path / "suite"
    shutil.copytree(SHIPPED, folder)
    index = json.loads((folder / "suite.json").read_text())
    index["course"]["episode_ratio"] = 1.0
    (folder / "suite.json").write_text(json.dumps(index))
    assert load_suite(folder).fingerprint != load_suite().fingerprint


def test_evaluation_runs_the_suites_course_scaled_to_the_episode():
    """The agent walks the suite's course: from its start, as far as its training episodes
    allow at the course's pace (a 400-step budget: a fifth of the 22 m), in episodes 2.5x its
    training ones (the reference's 5000 steps for the paper's 2000)."""
    course = load_suite().course
    for budget, steps, length in (
        ("paper", 5000, 22.0),
        ("workstation", 5000, 22.0),
        ("laptop", 1000, 4.4),
        ("smoke", 125, 0.55),
    ):
        rules = course.rules(load([f"budget={budget}"]).agent)
        assert rules.start_x == course.start_x and rules.max_episode_steps == steps
        assert rules.finish_x - rules.start_x == pytest.approx(length)


def _walk(rules, speed: float) -> tuple[bool, float]:
    """(finished, return) of a robot gliding straight along +x at `speed` (level, no lateral
    motion), through the task's real reward and episode rules, until the episode ends."""
    env = TerrainEnv(rules, load(["budget=paper"]).terrain)
    task = HexapodTask(rules, layout(env.model), 20.0)
    qpos, qvel, sd = np.zeros((1, 25)), np.zeros((1, 24)), np.zeros((1, 24))
    qpos[0, :4] = rules.start_x, 0.0, 0.2, 1.0
    qvel[0, 0] = speed
    state = EpisodeState.zeros(1)
    task.begin(qpos, state, slice(None))
    total, done = 0.0, False
    while not done:
        qpos[0, 0] += speed * rules.timestep
        reward, terminated, truncated, _ = task.step(qpos, qvel, sd, state)
        total, done = total + reward[0], bool(terminated[0] or truncated[0])
    return bool(state.finished[0]), total


@pytest.mark.parametrize("budget", ["smoke", "laptop", "workstation"])
def test_solved_asks_the_papers_speed_at_every_budget(budget: str) -> None:
    """At the target speed the scaled course is finished with a return over the run's solve
    score (2000 x its score scale); at half that speed the episode ends before the line."""
    cfg = load([f"budget={budget}"])
    rules = load_suite().course.rules(cfg.agent)
    solve = compose([], config_name=EVALUATE.name).solve_score * cfg.budget.score_scale
    finished, total = _walk(rules, cfg.agent.reward.target_speed)
    assert finished and total >= solve
    finished, _ = _walk(rules, cfg.agent.reward.target_speed / 2)
    assert not finished


def test_check_command_reports_a_mismatch_in_one_line(tmp_path):
    folder = tmp_path / "suite"
    shutil.copytree(SHIPPED, folder)
    index = json.loads((folder / "suite.json").read_text())
    index["terrains"][0]["seed"] += 1
    (folder / "suite.json").write_text(json.dumps(index))
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "epoet.eval.suite",
            f"out={folder}",
            "check=true",
            "max_heights=[0.4]",
            "children=1",
        ],
        capture_output=True,
        text=True,
        cwd=ROOT,
    )
    assert proc.returncode == 2
    assert proc.stderr.startswith("error: suite") and "differs" in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1


def test_suites_are_named_shipped_paper_or_by_their_folder(tmp_path, monkeypatch):
    """A suite's name keys its evaluations in a run: "shipped" and "paper" for the named suites
    (by name or by their folder), any other folder its basename in [A-Za-z0-9_.-], "dir-" before
    a basename that is a named suite's name, so no folder passes for a named suite."""
    authors()  # the paper suite's folder is their files' conversion
    assert load_suite().name == load_suite("shipped").name == load_suite(SHIPPED).name == "shipped"
    for basename, name in (
        ("my suite", "my_suite"),
        ("paper", "dir-paper"),
        ("shipped", "dir-shipped"),
    ):
        shutil.copytree(SHIPPED, tmp_path / basename)
        assert load_suite(tmp_path / basename).name == name
    # "paper" names the paper suite's folder (in the authors' files' conversion, under the
    # cache); while it is missing, the usual one-line error
    monkeypatch.setitem(suite_module.SUITES, "paper", lambda: tmp_path / "nowhere")
    with pytest.raises(SuiteError, match="nowhere is not a suite folder: it has no suite.json"):
        load_suite("paper")
    monkeypatch.setenv("EPOET_CACHE", str(tmp_path))
    monkeypatch.setitem(suite_module.SUITES, "paper", lambda: tmp_path / "my suite")
    paper = load_suite("paper")
    assert paper.name == "paper" and paper.folder == tmp_path / "my suite"
    assert load_suite(tmp_path / "my suite").name == "paper"  # its folder, given by path


def test_example_terrain_names_a_terrain_of_the_given_suite(tmp_path):
    shipped = load_suite()
    first_medium = next(t.name for t in shipped.terrains if t.level == "medium")
    assert example_terrain() == example_terrain(suite=shipped) == first_medium
    picks = [next(t for t in shipped.terrains if t.level == level) for level in ("hard", "extreme")]
    index = json.loads((SHIPPED / "suite.json").read_text())
    index["terrains"] = [
        {**e, "name": f"x_{e['name']}"}
        for e in index["terrains"]
        if e["name"] in {t.name for t in picks}
    ]
    tmp_path.joinpath("suite.json").write_text(json.dumps(index))
    with np.load(SHIPPED / "heights.npz") as heights:
        np.savez(tmp_path / "heights.npz", **{f"x_{t.name}": heights[t.name] for t in picks})
    other = load_suite(tmp_path)
    assert sorted(t.level for t in other.terrains) == ["extreme", "hard"]
    assert example_terrain(suite=other) == other.terrains[0].name  # no medium: its first
    assert example_terrain("extreme", other) == f"x_{picks[1].name}"
