"""The paper's statistic first: mean success over a fixed suite, with intervals over seeds.

The paper's Table 1 reports the mean success over its 32 terrains. Success on a terrain with 5
episodes is nearly binary, so the IQM over runs x terrains (analysis.stats) trims the easy and
the hard terrains away and reads a different number; and the suite is fixed and shared by
every algorithm, so its terrains are not a random draw to resample. Here the only random draw
is the training seed:

- **Mean success** of an algorithm at a mark: the mean over its runs of each run's mean success
  over the suite's terrains (the paper's number for one agent, averaged over seeds).
- **Its 95 % interval**: Student's t over the runs' means (n - 1 degrees of freedom); none for
  one run. Not clipped to [0, 100] %: a bound past either end says how few the seeds are.
- **Paired difference** X - Y: the mean over the same terrains of X's mean success minus Y's;
  95 % percentile bootstrap over each algorithm's runs (terrains fixed), seeded by the scores
  it resamples (`analysis.stats.stable_seed`).
- **Ties ceiling of P(X > Y)**: on a terrain that every run of X and of Y solves, or that every
  one fails, P(X > Y) is 1/2 whatever the algorithms are; with k of n terrains tied so, the
  largest P(X > Y) the pair can show is (n - k/2) / n.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy import stats as scipy_stats

from analysis.stats import CONFIDENCE, REPS, SEED, canonical, stable_seed


def mean_interval(run_means: Sequence[float]) -> tuple[float, float, float]:
    """Mean over runs and its 95 % t interval (NaN bounds for a single run)."""
    values = np.asarray(run_means, dtype=float)
    mean = float(values.mean())
    if len(values) < 2:
        return mean, float("nan"), float("nan")
    half = scipy_stats.t.ppf(0.5 + CONFIDENCE / 2, len(values) - 1) * scipy_stats.sem(values)
    return mean, mean - float(half), mean + float(half)


def difference_interval(
    x: np.ndarray, y: np.ndarray, reps: int = REPS, seed: int = SEED
) -> tuple[float, float, float]:
    """Mean success of X minus Y over the same terrains ((runs, terrains) each) and its 95 %
    bootstrap interval over each algorithm's runs."""
    x, y = canonical(x), canonical(y)
    point = float(x.mean() - y.mean())
    rng = np.random.default_rng(stable_seed(seed, x, y))
    draws = x[rng.integers(0, len(x), (reps, len(x)))].mean(axis=(1, 2)) - y[
        rng.integers(0, len(y), (reps, len(y)))
    ].mean(axis=(1, 2))
    tail = 100 * (1 - CONFIDENCE) / 2
    low, high = np.percentile(draws, [tail, 100 - tail])
    return point, float(low), float(high)


def ties_ceiling(x: np.ndarray, y: np.ndarray) -> float:
    """The largest P(X > Y) the runs allow: terrains where every run of both scores the same
    (all solved, all failed) hold it at 1/2."""
    both = np.concatenate([x, y])
    tied = (both == both[:1]).all(axis=0)
    return float(1.0 - 0.5 * tied.mean())
