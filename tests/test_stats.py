"""The statistics beside Tables 1-2 (analysis/stats.py), on hand-made episodes whose answers are
known without the code under test."""

from __future__ import annotations

import itertools

import numpy as np
import pandas as pd
import pytest

from analysis.stats import (
    CONFIDENCE,
    canonical,
    iqm,
    iqm_interval,
    iqm_table,
    poi,
    poi_interval,
    poi_table,
    rliable,
    score_matrices,
    seeded,
    stable_seed,
)
from analysis.stats_report import write_stats
from analysis.tables import to_markdown


def episodes_of(
    scores: dict[str, np.ndarray], solved: dict[str, np.ndarray] | None = None, spread: float = 0.5
) -> pd.DataFrame:
    """Two episodes per (run, terrain) whose returns average to scores[algo][run, terrain]
    (one spread below, one above) and whose `solved` is solved[algo][run, terrain]."""
    rows = []
    for algo, matrix in scores.items():
        for run, terrain in itertools.product(*map(range, matrix.shape)):
            for sign in (-1, 1):
                rows.append(
                    {
                        "run_id": f"{algo}-{run}",
                        "algo": algo,
                        "seed": str(run),
                        "terrain": f"t{terrain}",
                        "level": "easy",
                        "return": matrix[run, terrain] + sign * spread,
                        "solved": bool(solved[algo][run, terrain]) if solved else False,
                    }
                )
    return pd.DataFrame(rows)


def test_the_iqm_is_the_mean_of_the_middle_half():
    values = np.arange(1.0, 9.0).reshape(2, 4)  # 2 runs x 4 terrains: 1..8
    middle = sorted(values.ravel())[2:6]  # drop the lowest and the highest quarter
    assert middle == [3.0, 4.0, 5.0, 6.0]
    solved = values > 4  # entries 0,0,0,0,1,1,1,1: middle 0,0,1,1
    table = iqm_table(episodes_of({"ppo": values}, {"ppo": solved}), reps=300).set_index("score")
    assert table.loc["return", "iqm"] == pytest.approx(sum(middle) / 4)  # 4.5
    assert table.loc["success", "iqm"] == pytest.approx(0.5)
    for score in ("return", "success"):
        row = table.loc[score]
        assert row.ci_low <= row.iqm <= row.ci_high
        assert row.runs == 2 and row.terrains == 4 and row.resampled == "runs and terrains"
    # a fixed seed: the same intervals on every call
    again = iqm_table(episodes_of({"ppo": values}, {"ppo": solved}), reps=300)
    assert again.equals(table.reset_index()[again.columns])


@pytest.mark.parametrize("shape", [(1, 1), (1, 32), (3, 32), (5, 9), (4, 7)])
def test_the_iqm_is_rliables_to_the_bit(shape):
    """The IQM the bootstraps call is rliable's `aggregate_iqm` bit for bit, on returns, on
    success rates full of ties and on a matrix with one value."""
    rng = np.random.default_rng(sum(shape))
    for matrix in (
        rng.normal(1000.0, 800.0, shape),
        rng.choice([0.0, 20.0, 40.0, 60.0, 80.0, 100.0], shape),
        np.full(shape, 2000.0),
    ):
        assert iqm(matrix)[0] == rliable()[1].aggregate_iqm(matrix)
        resampled = matrix[rng.integers(0, shape[0], shape[0])][
            :, rng.integers(0, shape[1], shape[1])
        ]
        assert iqm(resampled)[0] == rliable()[1].aggregate_iqm(resampled)


def _arch_poi_interval(x: np.ndarray, y: np.ndarray, reps: int, seed: int) -> np.ndarray:
    """The pair bootstrap as the libraries compute it: rliable's independent stratified
    bootstrap with one terrain draw shared by x and y, arch's percentile interval, one
    resample at a time."""

    class TerrainsAndRuns(rliable()[0].StratifiedIndependentBootstrap):
        def update_indices(self):
            positional, keywords = super().update_indices()
            terrains = self._args_shapes[0][1]
            shared = np.random.choice(terrains, (1, terrains), replace=True)
            return [(runs, shared) for runs, *_ in positional], keywords

    np.random.seed(seed)
    return TerrainsAndRuns(x, y).conf_int(
        lambda a, b: np.array([poi(a, b)]), reps=reps, size=CONFIDENCE, method="percentile"
    )[:, 0]


@pytest.mark.parametrize("shapes", [(3, 3, 32), (2, 3, 32), (1, 1, 9), (5, 2, 7), (3, 3, 1)])
def test_the_probability_of_improvements_interval_is_the_libraries_to_the_bit(shapes):
    """`poi_interval`'s batched bootstrap gives the interval arch and rliable give, bit for
    bit, on returns, on success rates full of ties and on equal constants."""
    runs_x, runs_y, terrains = shapes
    rng = np.random.default_rng(sum(shapes))
    levels = [0.0, 20.0, 40.0, 60.0, 80.0, 100.0]
    for x, y in (
        (
            rng.normal(1000.0, 800.0, (runs_x, terrains)),
            rng.normal(900.0, 800.0, (runs_y, terrains)),
        ),
        (rng.choice(levels, (runs_x, terrains)), rng.choice(levels, (runs_y, terrains))),
        (np.full((runs_x, terrains), 100.0), np.full((runs_y, terrains), 100.0)),
    ):
        _, low, high = poi_interval(x, y, reps=500, seed=3)
        x, y = canonical(x), canonical(y)  # as poi_interval orders the runs before drawing
        expected = _arch_poi_interval(x, y, reps=500, seed=stable_seed(3, x, y))
        assert (low, high) == tuple(expected)


@pytest.mark.parametrize("shape", [(3, 32), (2, 32), (1, 9), (5, 7), (3, 1), (15, 45)])
def test_the_iqms_interval_is_the_libraries_to_the_bit(shape):
    """`iqm_interval`'s batched bootstrap gives rliable's `get_interval_estimates` (its
    stratified bootstrap over runs and terrains, arch's percentile interval), bit for bit, on
    returns, on success rates full of ties and on constants; its seed does not depend on the
    order of the runs, but its draws do, as the libraries' do."""
    rng = np.random.default_rng(sum(shape))
    levels = [0.0, 20.0, 40.0, 60.0, 80.0, 100.0]
    for matrix in (
        rng.normal(1000.0, 800.0, shape),
        rng.choice(levels, shape),
        np.full(shape, 100.0),
    ):
        with seeded(stable_seed(3, canonical(matrix))):
            point, interval = rliable()[0].get_interval_estimates(
                {"x": matrix},
                iqm,
                task_bootstrap=True,
                reps=500,
                confidence_interval_size=CONFIDENCE,
            )
        expected = (point["x"][0], interval["x"][0][0], interval["x"][1][0])
        assert iqm_interval(matrix, reps=500, seed=3) == expected


def test_score_matrices_are_per_run_and_terrain_means():
    values = np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]])
    matrices = score_matrices(episodes_of({"sac": values}, spread=3.0), "return")
    np.testing.assert_allclose(matrices["sac"], values)  # each entry: (v - 3 + v + 3) / 2


def test_an_algorithm_better_on_every_terrain_has_probability_of_improvement_1():
    rng = np.random.default_rng(0)
    worse = rng.uniform(0, 10, (3, 5))
    better = worse.max() + 1 + rng.uniform(0, 10, (3, 5))  # every run above every run
    point, low, high = poi_interval(better, worse, reps=300)
    assert (point, low, high) == (1.0, 1.0, 1.0)
    point, low, high = poi_interval(worse, better, reps=300)
    assert (point, low, high) == (0.0, 0.0, 0.0)
    same = poi_interval(worse, worse.copy(), reps=300)
    assert same[0] == 0.5


def test_probability_of_improvement_by_hand_and_as_rliable_computes_it():
    # terrain 0: 1 < 2 (0); terrain 1: 3 > 2 (1); terrain 2: a tie (1/2): mean 0.5
    x, y = np.array([[1.0, 3.0, 2.0]]), np.array([[2.0, 2.0, 2.0]])
    assert poi(x, y) == pytest.approx(0.5)
    # 2 runs against 3 on one terrain, 6 pairs: x > y in (4, 1), (4, 3), (4, 2), (2, 1), a tie
    # in (2, 2), and (2, 3) lost: (4 + 0.5) / 6
    assert poi(np.array([[4.0], [2.0]]), np.array([[1.0], [3.0], [2.0]])) == pytest.approx(4.5 / 6)
    # the vectorised form is rliable's number, ties and unequal run counts included
    rng = np.random.default_rng(1)
    for runs_x, runs_y in ((3, 3), (2, 3), (1, 1), (1, 4)):
        a = rng.integers(0, 4, (runs_x, 6)).astype(float)
        b = rng.integers(0, 4, (runs_y, 6)).astype(float)
        assert poi(a, b) == pytest.approx(rliable()[1].probability_of_improvement(a, b))


def test_pairs_read_as_the_papers_claims_and_one_run_is_said(tmp_path):
    ones = np.ones((1, 3))
    episodes = episodes_of(
        {"ppo": ones, "sac": 2 * ones, "epoet": 3 * ones},
        {"ppo": ones * 0, "sac": ones * 0, "epoet": ones},
    )
    table = poi_table(episodes, reps=200)
    assert list(zip(table.x, table.y)) == [("sac", "ppo"), ("epoet", "ppo"), ("epoet", "sac")] * 2
    ret = table[table.score == "return"]
    assert list(ret.poi) == [1.0, 1.0, 1.0]
    success = table[table.score == "success"].set_index(["x", "y"]).poi
    assert success[("sac", "ppo")] == 0.5 and success[("epoet", "sac")] == 1.0
    assert set(table.resampled) == {"terrains only (1 run each)"}

    written = write_stats(episodes, tmp_path, "shipped", "1", to_markdown, reps=200)
    assert {p.name for p in written} == {
        f"{n}_shipped.{e}" for n in ("iqm", "poi") for e in ("csv", "md", "tex", "png")
    }
    text = (tmp_path / "iqm_shipped.md").read_text()
    assert "One run only (ppo, sac, epoet)" in text and "terrains only" in text
    assert "\\begin{tabular}" in (tmp_path / "poi_shipped.tex").read_text()
    assert (tmp_path / "iqm_shipped.png").read_bytes()[:4] == b"\x89PNG"


def test_an_interval_depends_only_on_its_own_runs():
    """The same three runs give the same IQM interval alone, beside other algorithms (listed
    before it in table order, so a shared random stream would have been drawn from first), and
    with their runs read in another order; so does a pair's probability of improvement."""
    rng = np.random.default_rng(7)
    mine = rng.uniform(0, 3000, (3, 8))
    others = {algo: rng.uniform(0, 3000, (3, 8)) for algo in ("ppo", "sac")}

    def iqm_row(scores: dict[str, np.ndarray]) -> pd.Series:
        table = iqm_table(episodes_of(scores), reps=300)
        return table[(table.algo == "epoet") & (table.score == "return")].iloc[0]

    alone = iqm_row({"epoet": mine})
    crowded = iqm_row({**others, "epoet": mine})
    reordered = iqm_row({"epoet": mine[::-1]})
    for row in (crowded, reordered):
        assert (row.ci_low, row.ci_high, row.iqm) == (alone.ci_low, alone.ci_high, alone.iqm)
    assert alone.ci_low < alone.iqm < alone.ci_high  # a real interval, not a point

    def poi_row(scores: dict[str, np.ndarray]) -> pd.Series:
        table = poi_table(episodes_of(scores), reps=300)
        return table[(table.x == "epoet") & (table.y == "sac") & (table.score == "return")].iloc[0]

    pair = poi_row({"sac": others["sac"], "epoet": mine})
    crowded_pair = poi_row({**others, "epoet": mine[::-1]})
    assert (crowded_pair.ci_low, crowded_pair.ci_high) == (pair.ci_low, pair.ci_high)
