"""Where a run's evaluation on a suite lives in its MLflow run: metric, tag and artifact names
keyed by the suite's name (`epoet.eval.suite`: "shipped", "paper", or a folder's name), so one
run evaluated on several suites keeps each suite's results side by side.

- metrics (step 0) `suite/<name>/success_rate`, `suite/<name>/success_rate_<level>`,
  `suite/<name>/return_mean`, `suite/<name>/forward_distance_mean`, `suite/<name>/finish_rate`;
- tags `eval_suite/<name>` (the suite's fingerprint), `eval_course_scale/<name>`,
  `eval_episodes/<name>`;
- artifacts `evaluation/<name>/` (episodes.csv, actions.npz, summary.json).

Runs logged before evaluations were keyed by suite hold the unkeyed names (`suite/success_rate`,
`eval_suite`, `evaluation/episodes.csv`, ...), those of their latest evaluation. Readers take
them as the evaluation on a suite when the unkeyed `eval_suite` tag is that suite's fingerprint
(`logged_evaluation`), and the unkeyed metrics as the shipped suite's (`suite_metric`: the
end-of-run evaluation was on it).

No heavy imports: the sweep callback reads these names too.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

RESULTS = "evaluation"  # the artifact folder, and the default results folder name
SHIPPED_NAME = "shipped"  # the shipped suite's name (epoet/suite/)
PAPER_NAME = "paper"  # the paper's suite (the authors' evaluation genomes)
ADMITTED_NAME = "admitted"  # the validation suite (genomes the authors' runs admitted)
NAMED_SUITES = (SHIPPED_NAME, PAPER_NAME, ADMITTED_NAME)  # what `suite=<name>` takes
SUITE_TAG = "eval_suite"
SCALE_TAG = "eval_course_scale"
EPISODES_TAG = "eval_episodes"


def metric(suite: str, stat: str) -> str:
    """The metric of `stat` (success_rate, return_mean, ...) on the suite named `suite`."""
    return f"suite/{suite}/{stat}"


def tag(base: str, suite: str) -> str:
    """`base` (SUITE_TAG, SCALE_TAG, EPISODES_TAG) for the suite named `suite`."""
    return f"{base}/{suite}"


def artifacts(suite: str) -> str:
    """The artifact folder of the evaluation on the suite named `suite`."""
    return f"{RESULTS}/{suite}"


@dataclass(frozen=True)
class Logged:
    """A run's evaluation on one suite, as its tags record it."""

    artifacts: str  # the folder holding episodes.csv, actions.npz, summary.json
    course_scale: str


def suite_argument(suite: str, folder: object) -> str:
    """What names the suite `suite` (in `folder`) to the commands' `suite=`: a named suite by
    its name, any other by its folder."""
    return suite if suite in NAMED_SUITES else str(folder)


def logged_evaluation(tags: Mapping[str, str], suite: str, fingerprint: str) -> Logged | None:
    """The run's evaluation on the suite named `suite` with this fingerprint; None without one
    (none under that name, or one of other contents: another folder of the same name)."""
    if tags.get(tag(SUITE_TAG, suite)) == fingerprint:
        return Logged(artifacts(suite), tags.get(tag(SCALE_TAG, suite), "1"))
    if tags.get(SUITE_TAG) == fingerprint:  # logged before evaluations were keyed by suite
        return Logged(RESULTS, tags.get(SCALE_TAG, "1"))
    return None


def suite_metric(metrics: Mapping[str, float], suite: str, stat: str) -> float | None:
    """A run's `stat` on the suite named `suite` (its last value); for the shipped suite, a run
    logged before evaluations were keyed by suite gives its unkeyed metric."""
    value = metrics.get(metric(suite, stat))
    if value is None and suite == SHIPPED_NAME:
        value = metrics.get(f"suite/{stat}")
    return value
