"""Statistics that can separate algorithms with few runs (Agarwal et al. 2021, `rliable`), beside
the paper-style mean ± std of Tables 1-2 (`analysis.tables`, which writes both).

Per suite, from the episodes of every run (`analysis.tables.episodes_of` or the records):

- **Score matrix** of an algorithm: shape (runs, terrains); entry [r, t] is run r's mean over
  its episodes on terrain t: the fraction solved (success) or the mean episode return (return).
  Terrains are in the suite's order, the same columns for every algorithm.
- **IQM** (interquartile mean): the mean of the middle 50 % of the matrix's entries (25 % cut at
  each end, over runs and terrains together: `rliable.metrics.aggregate_iqm`). Less swayed by
  a few outlying terrains or seeds than the mean, less wasteful than the median.
- **95 % interval of the IQM**: percentile stratified bootstrap
  (`rliable.library.get_interval_estimates`, `task_bootstrap=True`): each resample draws the
  terrains with replacement and, within each drawn terrain, the algorithm's runs with
  replacement; the interval is the 2.5 and 97.5 percentiles of the IQM over `REPS` resamples.
  It answers "what IQM would another set of seeds on another draw of similar terrains give?".
  With one run the run draw changes nothing: the interval comes from the terrains only (how
  the score varies over the suite's terrains, not over training seeds); the output says so.
- **Probability of improvement** P(X > Y) of algorithm X over Y: for each terrain the
  probability that a random run of X scores above a random run of Y (ties count one half: the
  Mann-Whitney U statistic over nx x ny run pairs), averaged over the terrains
  (`rliable.metrics.probability_of_improvement`). 0.5: no difference; 1: X's every run beats Y's
  every run on every terrain. Its 95 % interval: the same stratified bootstrap, each
  algorithm's runs drawn independently within each terrain (rliable's
  `StratifiedIndependentBootstrap`) and one draw of terrains shared by X and Y (the pair is
  compared terrain by terrain; rliable's pair bootstrap leaves the terrain draw out, so it is
  added here, as `task_bootstrap=True` adds it for one algorithm). Pairs are listed with X after
  Y in table order (ppo, sac, vmpo, epoet, epoet_sac), so each reads as the paper's claim
  (ePOET-SAC > ePOET, ePOET > SAC, SAC > PPO); P(Y > X) = 1 - P(X > Y).

An interval is a function of the runs it summarises only: each bootstrap draws from a generator
seeded by `SEED` and a hash of its own scores (`stable_seed`; the runs in a canonical order,
`canonical`), never from one stream shared with the other algorithms, so the same runs give
the same interval whichever other runs share their folder or store, in whatever order. The
probability of improvement's point estimate comes from rliable; inside the bootstrap it is
`poi`, the same number vectorised (rliable's calls scipy once per terrain, ~25 ms per
resample), over all resamples at once (`poi_interval`: rliable's and arch's draws and
percentiles, to the bit). The IQM, point and bootstrap, is `iqm`: scipy's trim_mean steps
without its per-call argument handling, rliable's number to the bit; its interval is batched
the same way (`iqm_interval`). tests/test_stats.py checks each against the libraries.

analysis/stats_report.py writes these numbers as tables and figures.
"""

from __future__ import annotations

import hashlib
import itertools
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from functools import cache

import numpy as np
import pandas as pd

from analysis.store import in_order

REPS = 2000  # bootstrap resamples per interval
SEED = 0  # with the scores, seeds each bootstrap (stable_seed): reproducible intervals
CONFIDENCE = 0.95
METRICS = {"success": "solved", "return": "return"}  # score -> episodes.csv column
LABELS = {"success": "success rate (%)", "return": "return"}


@cache
def rliable():
    """rliable's library and metrics modules, imported on first use (about a second).

    rliable 1.2 needs arch < 8, and arch 7's package import decorates one of its model classes
    with pandas' private `deprecate_kwarg(old, new)`, which pandas 3 made
    `deprecate_kwarg(warning class, old, new)`: the import fails with a TypeError. For the
    import only, that decorator accepts the old call (as a FutureWarning); pandas is restored
    afterwards. (arch's bootstrap, the part rliable uses, does not touch it.)"""
    import pandas.util._decorators as decorators

    original = decorators.deprecate_kwarg

    def old_call(klass, *args, **kwargs):
        if isinstance(klass, str):
            return original(FutureWarning, klass, *args, **kwargs)
        return original(klass, *args, **kwargs)

    decorators.deprecate_kwarg = old_call
    try:
        from rliable import library, metrics
    finally:
        decorators.deprecate_kwarg = original
    return library, metrics


@contextmanager
def seeded(seed: int) -> Iterator[None]:
    """rliable's stratified bootstraps draw from numpy's global generator: seed it for the call
    and give it back its state afterwards."""
    state = np.random.get_state()
    np.random.seed(seed)
    try:
        yield
    finally:
        np.random.set_state(state)


def terrain_order(episodes: pd.DataFrame) -> list[str]:
    """The suite's terrains in the order the evaluations list them."""
    return list(dict.fromkeys(episodes.terrain))


def score_matrices(episodes: pd.DataFrame, score: str) -> dict[str, np.ndarray]:
    """Per algorithm (table order) its (runs, terrains) matrix: each run's mean over its
    episodes on each terrain of the `score` ("success" or "return")."""
    column, terrains = METRICS[score], terrain_order(episodes)
    matrices = {}
    for algo in in_order(episodes.algo):
        mine = episodes[episodes.algo == algo]
        table = (
            mine.assign(value=mine[column].astype(float))
            .groupby(["run_id", "terrain"], sort=False)
            .value.mean()
            .unstack("terrain")
        )
        table = table.reindex(index=list(dict.fromkeys(mine.run_id)), columns=terrains)
        if table.isna().any().any():
            missing = table.columns[table.isna().any()].tolist()
            raise ValueError(
                f"{algo} has runs without episodes on terrains {missing[:3]}: "
                f"every run must be evaluated on the same suite"
            )
        matrices[algo] = table.to_numpy()
    return matrices


def canonical(matrix: np.ndarray) -> np.ndarray:
    """The (runs, terrains) matrix with its runs (rows) sorted, so a bootstrap sees the same
    matrix whatever order the runs were read in."""
    return matrix[np.lexsort(matrix.T[::-1])] if matrix.size else matrix


def stable_seed(seed: int, *matrices: np.ndarray) -> int:
    """A bootstrap's seed from `seed` and the scores it resamples only (sha256: the same on
    every machine and Python, unlike `hash`)."""
    digest = hashlib.sha256(str(seed).encode())
    for matrix in matrices:
        digest.update(str(matrix.shape).encode())
        digest.update(np.ascontiguousarray(matrix, dtype=np.float64).tobytes())
    return int.from_bytes(digest.digest()[:4], "little")


def iqm(scores: np.ndarray) -> np.ndarray:
    """rliable's IQM, scipy's 25 % `trim_mean` of every run x terrain entry, with scipy's own
    steps (the same partition and slice, so the same bits) but not its per-call argument
    handling, most of the time of a bootstrap that calls this thousands of times."""
    return _iqms(np.asarray(scores, dtype=np.float64).reshape(1, -1))


def _iqms(flat: np.ndarray) -> np.ndarray:
    """`iqm` of each row of `flat` (rows, entries): each row partitioned and sliced as scipy's
    trim_mean does one array."""
    cut = int(0.25 * flat.shape[1])
    kept = np.partition(flat, (cut, flat.shape[1] - cut - 1), axis=1)[:, cut : flat.shape[1] - cut]
    return kept.mean(axis=1)


def _percentile_interval(estimates: np.ndarray) -> tuple[float, float]:
    """arch's percentile interval of bootstrap estimates, with its own arithmetic."""
    alpha = (1.0 - CONFIDENCE) / 2
    low, high = np.percentile(estimates, [100 * alpha, 100 * (1.0 - alpha)])
    return float(low), float(high)


def poi(x: np.ndarray, y: np.ndarray) -> float:
    """rliable's probability of improvement, vectorised: per terrain, over every (run of x, run
    of y) pair, P(x > y) + P(x = y) / 2; the mean over terrains."""
    return float(_pois(x[None], y[None])[0])


def _pois(xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
    """`poi` of each resample: xs (resamples, runs of x, terrains), ys likewise."""
    pairs = xs[:, :, None, :], ys[:, None, :, :]
    per_terrain = (pairs[0] > pairs[1]).mean(axis=(1, 2)) + 0.5 * (pairs[0] == pairs[1]).mean(
        axis=(1, 2)
    )
    return per_terrain.mean(axis=-1)


def resampled(runs: Sequence[int], names: Sequence[str] = ()) -> str:
    """What an interval is over, given the run counts of the algorithms it compares (`names`:
    theirs, for a pair)."""
    if max(runs) == 1:
        return "terrains only (1 run)" if len(runs) == 1 else "terrains only (1 run each)"
    single = [name for name, n in zip(names, runs) if n == 1]
    return f"runs and terrains ({single[0]}: 1 run)" if single else "runs and terrains"


def iqm_interval(
    matrix: np.ndarray, reps: int = REPS, seed: int = SEED
) -> tuple[float, float, float]:
    """IQM of a (runs, terrains) matrix and its 95 % interval: rliable's stratified bootstrap
    over runs and terrains (`task_bootstrap=True`) under arch's percentile interval, seeded by
    the matrix's scores alone (`canonical`: the seed, not the draws, ignores the runs' order), done
    in one batch as `poi_interval` is: the same draws in the same order (per resample the
    runs within each terrain, then the terrains), the same IQM of each resample, the same
    percentiles, so the same bits (tests/test_stats.py checks it against the libraries)."""
    runs, terrains = matrix.shape
    with seeded(stable_seed(seed, canonical(matrix))):
        # rliable's np.random.choice(n, shape) is np.random.randint(0, n, shape): the same
        # draws, without choice's argument handling (half of each call)
        draws = [
            (
                np.random.randint(0, runs, (runs, terrains)),
                np.random.randint(0, terrains, (1, terrains)),
            )
            for _ in range(reps)
        ]
    rows, columns = (np.stack(d) for d in zip(*draws))
    resampled = matrix[rows, columns].reshape(reps, -1)  # [r] = resample r, as `iqm` flattens it
    return (float(iqm(matrix)[0]), *_percentile_interval(_iqms(resampled)))


def iqm_table(episodes: pd.DataFrame, reps: int = REPS, seed: int = SEED) -> pd.DataFrame:
    """algo, score, runs, terrains, iqm, ci_low, ci_high, resampled, reps, seed: per algorithm
    and score, the IQM of its score matrix with its 95 % stratified-bootstrap interval."""
    rows = []
    for score in METRICS:
        for algo, matrix in score_matrices(episodes, score).items():
            point, low, high = iqm_interval(canonical(matrix), reps, seed)
            rows.append(
                {
                    "algo": algo,
                    "score": score,
                    "runs": matrix.shape[0],
                    "terrains": matrix.shape[1],
                    "iqm": point,
                    "ci_low": low,
                    "ci_high": high,
                    "resampled": resampled([matrix.shape[0]]),
                    "reps": reps,
                    "seed": seed,
                }
            )
    return pd.DataFrame(rows)


def poi_interval(
    x: np.ndarray, y: np.ndarray, reps: int = REPS, seed: int = SEED
) -> tuple[float, float, float]:
    """P(X > Y) (rliable's) and its 95 % interval over runs and terrains.

    The bootstrap is rliable's `StratifiedIndependentBootstrap` with a terrain draw shared by
    both algorithms (the module docstring), under arch's percentile interval, done in one
    batch: the same draws from numpy's global generator in the same order (per resample x's
    runs, y's runs, then the terrains), the same P(X > Y) of each resample and the same
    percentiles, so the same bits (tests/test_stats.py checks it against arch and rliable),
    without the per-resample index and resample bookkeeping that was most of a report's time."""
    x, y = canonical(x), canonical(y)
    point = float(rliable()[1].probability_of_improvement(x, y))
    (runs_x, terrains), runs_y = x.shape, y.shape[0]
    with seeded(stable_seed(seed, x, y)):
        draws = [
            (
                np.random.randint(0, runs_x, (runs_x, terrains)),  # `iqm_interval`: choice's draws
                np.random.randint(0, runs_y, (runs_y, terrains)),
                np.random.randint(0, terrains, (1, terrains)),
            )
            for _ in range(reps)
        ]
    rx, ry, shared = (np.stack(d) for d in zip(*draws))
    resampled = _pois(x[rx, shared], y[ry, shared])  # [r, i, t] = x[rx[r, i, t], shared[r, 0, t]]
    return (point, *_percentile_interval(resampled))


def poi_table(episodes: pd.DataFrame, reps: int = REPS, seed: int = SEED) -> pd.DataFrame:
    """x, y, score, poi, ci_low, ci_high, runs_x, runs_y, resampled, reps, seed: P(X > Y) for
    every pair of algorithms, X after Y in table order."""
    rows = []
    for score in METRICS:
        matrices = score_matrices(episodes, score)
        for y, x in itertools.combinations(matrices, 2):
            point, low, high = poi_interval(matrices[x], matrices[y], reps, seed)
            runs = (matrices[x].shape[0], matrices[y].shape[0])
            rows.append(
                {
                    "x": x,
                    "y": y,
                    "score": score,
                    "poi": point,
                    "ci_low": low,
                    "ci_high": high,
                    "runs_x": runs[0],
                    "runs_y": runs[1],
                    "resampled": resampled(runs, (x, y)),
                    "reps": reps,
                    "seed": seed,
                }
            )
    return pd.DataFrame(
        rows,
        columns=[
            "x",
            "y",
            "score",
            "poi",
            "ci_low",
            "ci_high",
            "runs_x",
            "runs_y",
            "resampled",
            "reps",
            "seed",
        ],
    )
