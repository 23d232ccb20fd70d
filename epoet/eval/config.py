"""The schemas of the commands around a trained agent (`python -m epoet.eval.<command>`): the
suite, evaluate, render, the gallery and the reference converter; registered with the run's
config in epoet/config.py."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, Optional

from epoet.core.schema import check, non_negative, positive
from epoet.envs.config import AgentConfig
from epoet.terrain.config import TerrainConfig
from epoet.tracking.config import TrackingConfig


@dataclass
class SuiteConfig:
    """`python -m epoet.eval.suite`: the fixed evaluation suite (docs/reference.md "Evaluation").

    Rounds of mutated CPPN children with a rising S; round r aims its children at level r
    (epoet/eval/suite_generation.py)."""

    KEY: ClassVar[str] = ""

    terrain: TerrainConfig  # the CPPN settings the terrains are drawn with (conf/terrain/)
    agent: AgentConfig  # the course (start_x .. finish_x) the roughness is read along
    episode_ratio: float  # evaluation episodes last this x the agent's training ones
    seed: int  # seeds the whole generation: the same seed, the same suite
    children: int  # children per round (lineages)
    max_heights: list[float]  # S of each round, metres: one round per entry
    max_tries: int  # mutations tried per child before taking the closest
    out: Optional[str]  # the suite folder written (or checked); null: the shipped suite
    check: bool  # regenerate and compare with `out`, write nothing

    def __post_init__(self) -> None:
        non_negative(self, "seed")
        positive(self, "children", "max_tries", "episode_ratio")
        check(
            len(self.max_heights) > 0
            and all(0 < s <= self.terrain.max_height_limit for s in self.max_heights),
            f"max_heights must be a non-empty list in (0, terrain.max_height_limit = "
            f"{self.terrain.max_height_limit}], got {self.max_heights}.",
        )


@dataclass
class AgentCommandConfig:
    """What the commands that run a trained agent share (evaluate, render)."""

    KEY: ClassVar[str] = ""

    run: Optional[str]  # required: a run folder, a policy file, an MLflow run id or its model
    # URI runs:/<run id>/agent, or an authors' agent reference:<run>/<agent>
    agent: AgentConfig  # episode rules for a bare policy file (a run brings its own)
    tracking: TrackingConfig  # the MLflow store a run id is looked up in and logged to
    suite: Optional[str]  # shipped, paper, admitted or a suite folder; null: shipped
    seed: int  # keys the episodes' starts
    epoet_3d: Optional[str]  # a copy of ml-tue/ePOET_3D (reference: agents, suite=paper);
    # null: the environment variable EPOET_3D, else ../shared/ePOET_3D beside the project

    def __post_init__(self) -> None:
        check(
            bool(self.run),
            "run is required: run=<run folder | policy file | MLflow run id | runs:/<id>/agent | reference:<run>/<agent>>.",
        )
        non_negative(self, "seed")


@dataclass
class EvaluateConfig(AgentCommandConfig):
    """`python -m epoet.eval.evaluate`: a trained agent on the evaluation suite."""

    episodes: int  # episodes per terrain
    solve_score: float  # "solved": finish line and this return (x the run's scale)
    action_samples: int  # actions kept per episode, for t-SNE
    processes: Optional[int]  # worker processes; null: one per available core
    out: Optional[str]  # results folder; null: <run folder>/evaluation/<suite>, else
    # ./evaluation/<run>/<suite> in the working directory

    def __post_init__(self) -> None:
        super().__post_init__()
        positive(self, "episodes")
        non_negative(self, "action_samples")
        check(
            self.processes is None or self.processes > 0,
            f"processes must be > 0 or null, got {self.processes}.",
        )


@dataclass
class RenderConfig(AgentCommandConfig):
    """`python -m epoet.eval.render`: an mp4 of a trained agent on one terrain."""

    terrain: Optional[str]  # required: a suite terrain's name or a terrain .npz file
    steps: Optional[int]  # steps to film; null: the run's episode length
    width: int  # video width in pixels (even)
    height: int  # video height in pixels (even)
    out: Optional[str]  # the mp4 written; null: videos/<run>_<terrain>.mp4

    def __post_init__(self) -> None:
        super().__post_init__()
        check(bool(self.terrain), "terrain is required: a suite terrain's name or an .npz file.")
        positive(self, "width", "height")
        check(self.steps is None or self.steps > 0, f"steps must be > 0, got {self.steps}.")


@dataclass
class GalleryConfig:
    """`python -m epoet.eval.gallery`: a root terrain and its mutated descendants as one PNG grid."""

    KEY: ClassVar[str] = ""

    terrain: TerrainConfig  # the terrain group: cppn (mutated chain) or bowl
    seed: int  # seeds the root terrain and each mutation
    n: int  # terrains drawn: the root and n - 1 descendants
    out: str  # folder for gallery.png and the terrains' npz files

    def __post_init__(self) -> None:
        non_negative(self, "seed")
        positive(self, "n")


@dataclass
class ReferenceConfig:
    """`python -m epoet.eval.reference`: convert the authors' published agents and evaluation
    terrains into epoet's formats (epoet/eval/reference/convert.py)."""

    KEY: ClassVar[str] = ""

    source: Optional[str]  # a copy of github.com/ml-tue/ePOET_3D; null: the epoet_3d setting
    out: Optional[str]  # the folder written (or checked); null: the cache commands read
    check: bool  # convert and compare with `out`, write nothing
