"""The paper's statistic and its intervals (analysis.mean_success)."""

from __future__ import annotations

import numpy as np
import pytest

from analysis.mean_success import difference_interval, mean_interval, ties_ceiling


def test_the_mean_over_seeds_has_a_t_interval_and_none_for_one_seed():
    mean, low, high = mean_interval([0.4, 0.5, 0.6])
    # t(0.975, 2 dof) = 4.303, standard error 0.1 / sqrt(3)
    assert mean == pytest.approx(0.5)
    assert (low, high) == pytest.approx((0.5 - 0.2484, 0.5 + 0.2484), abs=1e-4)
    point, low, high = mean_interval([0.7])
    assert point == 0.7 and np.isnan(low) and np.isnan(high)


def test_the_paired_difference_is_over_the_same_terrains_and_seeded_by_its_scores():
    x = np.array([[1.0, 1.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0], [1.0, 1.0, 1.0, 0.0]])
    y = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0]])
    point, low, high = difference_interval(x, y)
    assert point == pytest.approx(x.mean() - y.mean())  # 0.5 - 0.125
    assert low < point < high and -1.0 <= low and high <= 1.0
    # the same runs in another order, beside other algorithms: the same interval
    assert difference_interval(x[::-1], y[::-1]) == (point, low, high)
    same = np.ones((3, 4))
    assert difference_interval(same, same) == (0.0, 0.0, 0.0)


def test_terrains_every_run_ties_on_cap_the_probability_of_improvement():
    x = np.array([[1.0, 0.0, 1.0, 0.0], [1.0, 0.0, 1.0, 1.0]])
    y = np.array([[1.0, 0.0, 0.0, 0.0]])
    # terrains 0 (all solved) and 1 (all failed) are tied: (4 - 2 / 2) / 4
    assert ties_ceiling(x, y) == pytest.approx(0.75)
    assert ties_ceiling(np.eye(3), np.eye(3)[::-1]) == 1.0


def test_the_level_table_counts_medium_episodes_that_stop_at_the_step(tmp_path):
    """Four medium episodes (a solved one, two failed at 6 m and 7 m, one failed at 12 m) and
    one easy one: half the medium episodes, two thirds of the failed, end at the step."""
    import json

    import pandas as pd

    from analysis.levels import level_summary, level_table
    from analysis.records import EPISODES, FORMAT, RUN_FILE

    record = tmp_path / "epoet_s1"
    folder = record / "cpu60" / "agent" / "paper"
    folder.mkdir(parents=True)
    pd.DataFrame(
        {
            "level": ["medium"] * 4 + ["easy"],
            "finished": [True, False, False, False, True],
            "solved": [True, False, False, False, True],
            "forward_distance": [22.0, 6.0, 7.0, 12.0, 22.0],
        }
    ).to_csv(folder / EPISODES, index=False)
    run = {
        "format": FORMAT,
        "run_id": "r1",
        "algo": "epoet",
        "seed": "1",
        "started": "2026-01-01T00:00:00Z",
    }
    run["snapshots"] = {"60": {"best_agent": "agent", "evaluations": {"paper": {}}}}
    (record / RUN_FILE).write_text(json.dumps(run))
    [row] = level_table(tmp_path, "paper").to_dict("records")
    assert row["easy"] == 1.0 and row["medium"] == 0.25
    assert row["medium at step"] == 0.5 and row["failed medium at step"] == pytest.approx(2 / 3)
    assert row["failed medium distance (m)"] == pytest.approx(25 / 3)
    assert level_summary(level_table(tmp_path, "paper")).runs.tolist() == [1]
