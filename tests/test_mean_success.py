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
