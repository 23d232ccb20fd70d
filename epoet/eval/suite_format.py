"""What the suite's reader (epoet/eval/suite.py, whose docstring gives the folder format) and its
generator (epoet/eval/suite_generation.py) share: the format's version, the course and its
roughness, the difficulty levels, and how heights are stored."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from epoet.envs.config import AgentConfig
from epoet.envs.model import patch_variance

# 2: the reference's CPPN feature scale and 22 m course, and the course's own episode length.
SUITE_FORMAT = "epoet-suite/2"
SHIPPED = Path(__file__).resolve().parent.parent / "suite"  # the shipped suite's folder
LEVELS = ("easy", "medium", "hard", "extreme")
LEVEL_BOUNDS = (1e-3, 1e-2, 1e-1)  # m^2 of patch variance between consecutive levels
_QUANT = 65535


@dataclass(frozen=True)
class Course:
    """The strip the robot walks: x from start_x to finish_x, |y| <= half_width (metres), made
    for agents trained on `episode_steps`-step episodes; an evaluation episode may last
    episode_ratio x the agent's training episodes."""

    start_x: float
    finish_x: float
    half_width: float
    episode_steps: int
    episode_ratio: float

    @classmethod
    def of(cls, agent: AgentConfig, episode_ratio: float) -> Course:
        return cls(
            agent.start_x,
            agent.finish_x,
            agent.spawn_footprint,
            agent.max_episode_steps,
            episode_ratio,
        )

    def scale(self, agent: AgentConfig) -> float:
        """The course's share an agent trained on shorter episodes walks (1 at full length)."""
        return min(1.0, agent.max_episode_steps / self.episode_steps)

    def rules(self, agent: AgentConfig) -> AgentConfig:
        """`agent`'s episode rules on this course: its start, a finish line as far as the
        agent's episodes allow at the course's pace (the full course for episodes of
        `episode_steps` or more), and episodes `episode_ratio` x the agent's. So "solved"
        asks the same speed and return per step at every budget: a budget with a fifth of
        the episode walks a fifth of the course in a fifth of the time."""
        length = (self.finish_x - self.start_x) * self.scale(agent)
        return dataclasses.replace(
            agent,
            start_x=self.start_x,
            finish_x=self.start_x + length,
            max_episode_steps=max(1, round(self.episode_ratio * agent.max_episode_steps)),
        )

    def roughness(self, heightmap: np.ndarray, max_height: float, size: float) -> float:
        """Mean 5 x 5 patch variance of the heights (metres) over the course's cells."""
        n = heightmap.shape[0]
        axis = np.linspace(-size / 2, size / 2, n)
        rows = np.abs(axis) <= self.half_width
        cols = (axis >= self.start_x) & (axis <= self.finish_x)
        return float(patch_variance(heightmap * max_height)[np.ix_(rows, cols)].mean())


def level_of(roughness: float) -> str:
    return LEVELS[int(np.searchsorted(LEVEL_BOUNDS, roughness, side="right"))]


def quantize(heightmap: np.ndarray) -> np.ndarray:
    return np.rint(np.clip(heightmap, 0.0, 1.0) * _QUANT).astype(np.uint16)


def dequantize(q: np.ndarray) -> np.ndarray:
    return q.astype(np.float64) / _QUANT if q.dtype == np.uint16 else q.astype(np.float64)
