"""The batched rollout engine: many episodes, stepped in lockstep in one process.

Episodes run in `batch` slots, the simulations of one `mujoco.batch.Batch` (persistent: an MjData
each). The terrains of a call are loaded once each into their own copy of the model, and each
slot steps with its episode's copy (`Batch.set_models`), so slots on different terrains run side
by side and a job stream may mix terrains freely: a worker never drains its slots at the boundary
between two populations. Per control step the engine makes one batched policy call (each slot its
own parameters), writes the targets into the batch's ctrl rows, steps every running slot in one C
call, and computes reward, termination and the next observation for the whole batch with the
robot's `Task`, reading the batch's bound qpos/qvel/sensordata arrays in place. Policy, task and
bookkeeping are compiled (numba), one call each over all rows: no Python runs per slot within a
step, and the time outside MuJoCo is a small share of a step (bench/epoet_iteration.py).

Each step is mj_step followed by the position and velocity stages at the new state
(`mjSTAGE_VEL`), so the contact sensors describe the state the joint angles do; a persistent batch
starts its next step from those stages, so this costs nothing extra (the same work as
`epoet.envs.model.stepper`, bit for bit).

When an episode ends, its slot takes the next job straight away (spawned from that job's own
seed), so slots stay busy until the job stream runs dry; then finished slots simply stop being
stepped. An episode's result depends only on its parameters, its spawn seed and its terrain,
never on the batch size, the slot it ran in, the other terrains of the call or the worker that ran
it: each spawn settles on a fresh MjData and hands the slot its whole integration state
(warmstart included), and each policy row is computed independently.
"""

from __future__ import annotations

import copy
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass

import mujoco
import mujoco.batch
import numpy as np
from numba import njit

from epoet.envs.config import AgentConfig
from epoet.envs.model import Ground, build_model, layout, targets_rows
from epoet.envs.spawn import spawn
from epoet.envs.task import EpisodeState, Task
from epoet.rollout.policy import forward_rows, num_params, sizes_array
from epoet.terrain.config import TerrainConfig
from epoet.terrain.terrain import TerrainLike

TRANSITION_KEYS = ("episode", "obs", "action", "reward", "next_obs", "terminated")

_STAGE_VEL = int(mujoco.mjtStage.mjSTAGE_VEL)
_INTEGRATION = mujoco.mjtState.mjSTATE_INTEGRATION

Job = tuple[int, np.ndarray, int, int, bool]
"""One episode to run: (episode index, policy parameters (P,), spawn seed, terrain index,
whether its transitions are recorded)."""


@dataclass
class Episodes:
    """Results of a set of episodes, row e belonging to episode e.

    `transitions` (when recorded) holds one row per control step of every episode, grouped by
    episode and in time order within each: `episode` (int index), `obs`, `action` (the policy
    output), `reward`, `next_obs` (the observation after the step, terminal ones included) and
    `terminated` (a true end, not a time limit: SAC bootstraps through truncations). The per-
    episode action sequences are `action[episode == e]`.
    """

    returns: np.ndarray  # float64
    lengths: np.ndarray  # int64, control steps
    finished: np.ndarray  # bool, crossed the finish line
    transitions: dict[str, np.ndarray] | None = None


def merge_episodes(parts: Sequence[tuple[np.ndarray, Episodes]], n: int) -> Episodes:
    """One `Episodes` of size n from (episode indices, results) parts covering 0..n-1 once each."""
    index = np.concatenate([idx for idx, _ in parts])
    if index.shape != (n,) or not np.array_equal(np.sort(index), np.arange(n)):
        raise RuntimeError(
            f"rollout parts hold {index.size} episodes that do not cover each "
            f"of 0..{n - 1} exactly once."
        )
    order = np.argsort(index)
    returns, lengths, finished = (
        np.concatenate([getattr(ep, name) for _, ep in parts])[order]
        for name in ("returns", "lengths", "finished")
    )
    merged = Episodes(returns, lengths, finished)
    recorded = [ep.transitions for _, ep in parts if ep.transitions is not None]
    if recorded:
        merged.transitions = _group_by_episode(
            {key: np.concatenate([t[key] for t in recorded]) for key in TRANSITION_KEYS}
        )
    return merged


def _group_by_episode(transitions: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    # A stable sort keeps each episode's steps in time order.
    order = np.argsort(transitions["episode"], kind="stable")
    return {key: value[order] for key, value in transitions.items()}


def check_seeds(seeds: np.ndarray, name: str) -> np.ndarray:
    """Seeds as an int64 array; they must be integers >= 0 (np.random.default_rng's domain)."""
    seeds = np.asarray(seeds)
    if seeds.size and seeds.dtype.kind not in "iu":
        raise ValueError(f"{name} must be integers >= 0, got {seeds.dtype} values.")
    if seeds.size and seeds.min() < 0:
        raise ValueError(f"{name} must be integers >= 0, got {seeds.min()}.")
    return seeds.astype(np.int64)


class _Recorder:
    """Appends the recorded slots' transitions each step; made when the first recorded episode
    starts (which adds rows at its first step).

    Observations, actions and rewards are kept in float32, what SAC's replay stores: half the
    memory and the bytes sent back from the workers."""

    DTYPES = {
        "episode": np.int64,
        "obs": np.float32,
        "action": np.float32,
        "reward": np.float32,
        "next_obs": np.float32,
        "terminated": bool,
    }

    def __init__(self) -> None:
        self.chunks: dict[str, list[np.ndarray]] = {key: [] for key in TRANSITION_KEYS}

    def add(
        self,
        rows: np.ndarray,
        episode: np.ndarray,
        obs: np.ndarray,
        action: np.ndarray,
        reward: np.ndarray,
        next_obs: np.ndarray,
        terminated: np.ndarray,
    ) -> None:
        """The step's transitions of slots `rows`; `obs` holds those rows only (the engine
        takes them before it overwrites its observations), the other fields every slot."""
        values = (episode[rows], obs, action[rows], reward[rows], next_obs[rows], terminated[rows])
        for key, value in zip(TRANSITION_KEYS, values):
            # fancy indexing copied the rows (the engine reuses its buffers); float64 fields
            # are then cast to float32 (a second, row-sized copy)
            self.chunks[key].append(value.astype(self.DTYPES[key], copy=False))

    def result(self) -> dict[str, np.ndarray]:
        """Rows in step order; `merge_episodes` groups them by episode (a stable sort keeps
        each episode's steps in time order)."""
        return {key: np.concatenate(parts) for key, parts in self.chunks.items()}


@dataclass
class _Run:
    """Bookkeeping of one `run_jobs` call over its slots (arrays of shape (width,))."""

    state: EpisodeState
    returns: np.ndarray
    episode: np.ndarray  # job index per slot; -1 while idle
    running: np.ndarray
    recording: np.ndarray  # the slot's episode is recorded
    jobs: Iterator[Job]
    recorder: _Recorder | None = None  # made when the first recorded episode starts


@dataclass
class _Field:
    """One terrain of the current call, written into its own copy of the model."""

    model: mujoco.MjModel
    ground: Ground


@njit(cache=True)
def _tally(
    reward: np.ndarray,
    terminated: np.ndarray,
    truncated: np.ndarray,
    running: np.ndarray,
    returns: np.ndarray,
    done: np.ndarray,
) -> bool:
    """Add the running slots' rewards to their returns and mark those whose episode ended in
    `done`; whether any did. (One compiled call for what took four numpy calls a step.)"""
    any_done = False
    for i in range(running.size):
        if running[i]:
            returns[i] += reward[i]
        done[i] = running[i] and (terminated[i] or truncated[i])
        any_done = any_done or done[i]
    return any_done


class RolloutEngine:
    """Runs episodes of many parameter vectors on given terrains at close to raw MuJoCo speed."""

    def __init__(
        self, agent: AgentConfig, terrain: TerrainConfig, batch: int, layer_sizes: Sequence[int]
    ) -> None:
        """`batch` robots (the agent config's) step together (`workers.batch`); `layer_sizes`
        is the policy's."""
        if batch < 1:
            raise ValueError(f"batch must be >= 1, got {batch}.")
        self.agent = agent
        self.batch = int(batch)
        self.layer_sizes = tuple(layer_sizes)
        self.model = build_model(agent, terrain)  # the template each terrain's copy is made of
        self.layout = layout(self.model)
        self.task = Task(agent, self.layout, Ground(self.model).half_x)
        obs_dim, act_dim = self.task.obs_dim, self.task.act_dim
        if self.layer_sizes[0] != obs_dim or self.layer_sizes[-1] != act_dim:
            raise ValueError(
                f"layer_sizes must map the {agent.name}'s {obs_dim} observations to its "
                f"{act_dim} actions, got {self.layer_sizes}."
            )
        self.num_params = num_params(self.layer_sizes)
        self._sizes = sizes_array(self.layer_sizes)
        self._fields: list[_Field] = []
        m, b = self.model, self.batch
        # nthread=1: a worker process is one core's worth of work; the pool runs one per core.
        self._sims = mujoco.batch.Batch(m, nsim=b, nthread=1, persistent=True)
        # Live (b, n) views: state rows (qpos, qvel, ctrl) and the outputs refreshed by each call.
        self._qpos, self._qvel = self._sims.bind("qpos"), self._sims.bind("qvel")
        self._ctrl, self._sensor = self._sims.bind("ctrl"), self._sims.bind("sensordata")
        self._spawn_data = mujoco.MjData(m)  # episodes settle here, then move into their slot
        self._obs, self._actions = np.zeros((b, obs_dim)), np.zeros((b, act_dim))
        self._params = np.zeros((b, self.num_params))  # each slot's policy parameters
        self._slot_model = [self.model] * b  # the model (terrain) each slot steps with

    def set_terrains(self, terrains: Sequence[TerrainLike]) -> None:
        """The terrains that jobs name by index, each written into its own model copy."""
        for k, terrain in enumerate(terrains):
            if k == len(self._fields):
                model = copy.copy(self.model)
                self._fields.append(_Field(model, Ground(model)))
            field = self._fields[k]
            field.ground.set(
                field.model,
                np.asarray(terrain.heightmap),
                float(terrain.max_height),
                float(terrain.size),
            )

    def run(
        self,
        terrain: TerrainLike,
        params: np.ndarray,
        episode_seeds: np.ndarray,
        *,
        record: bool = False,
    ) -> Episodes:
        """Episode e runs policy `params[e]` from the start drawn by `default_rng(seeds[e])`."""
        params = np.asarray(params, dtype=np.float64)
        seeds = check_seeds(episode_seeds, "episode_seeds")
        if params.ndim != 2 or params.shape[1] != self.num_params:
            raise ValueError(f"params must have shape (N, {self.num_params}), got {params.shape}.")
        if seeds.shape != (params.shape[0],):
            raise ValueError(
                f"episode_seeds must have shape ({params.shape[0]},) to match "
                f"params, got {seeds.shape}."
            )
        if not len(seeds):
            raise ValueError("run needs at least one episode.")
        jobs = ((e, params[e], int(seeds[e]), 0, record) for e in range(len(seeds)))
        self.set_terrains([terrain])
        return merge_episodes([self.run_jobs(jobs, slots=len(seeds))], len(seeds))

    def run_jobs(
        self, jobs: Iterable[Job], *, slots: int | None = None
    ) -> tuple[np.ndarray, Episodes]:
        """Run jobs on their terrains (`set_terrains`) until the stream ends; jobs are pulled as
        slots free up.

        Returns the episode indices seen (ascending) and their results in that order (recorded
        transitions in step order, grouped by `merge_episodes`). `slots`
        caps the slots in use (default: all): fewer rows make each batched step cheaper, and a
        worker sharing a job queue should not hoard more jobs than its share.
        """
        width = self.batch if slots is None else max(1, min(int(slots), self.batch))
        run = _Run(
            EpisodeState.zeros(width),
            np.zeros(width),
            np.full(width, -1, dtype=np.int64),
            np.zeros(width, dtype=bool),
            np.zeros(width, dtype=bool),
            iter(jobs),
        )
        qpos, qvel, sensor = self._qpos[:width], self._qvel[:width], self._sensor[:width]
        obs, ctrl, actions = self._obs[:width], self._ctrl[:width], self._actions[:width]
        params, lay = self._params[:width], self.layout
        done = np.zeros(width, dtype=bool)
        results: list[tuple[int, float, int, bool]] = []

        self._start(run, range(width))
        active, recorded = self._active(run)
        while active is None or len(active):
            # Two calls, not one compiled function calling both: numba's on-disk cache would not
            # notice an edit to a function from another module inside it.
            forward_rows(params, self._sizes, obs, actions)
            # idle slots get controls too; they never step
            targets_rows(actions, lay.ctrl_low, lay.ctrl_span, lay.ctrl_index, ctrl)
            self._sims.step(active, stage=_STAGE_VEL)
            if len(recorded):
                before = obs[recorded].astype(np.float32)
            # Idle slots ride along in the task (their rows are stale and ignored): one call over
            # all rows is cheaper than selecting the active ones every step.
            reward, terminated, truncated, _ = self.task.step(qpos, qvel, sensor, run.state, obs)
            if len(recorded):
                assert run.recorder is not None  # made when a recorded episode started
                run.recorder.add(recorded, run.episode, before, actions, reward, obs, terminated)
            if _tally(reward, terminated, truncated, run.running, run.returns, done):
                ended = np.flatnonzero(done)
                results += [
                    (
                        int(run.episode[i]),
                        float(run.returns[i]),
                        int(run.state.steps[i]),
                        bool(run.state.finished[i]),
                    )
                    for i in ended
                ]
                run.running[ended] = False
                run.episode[ended] = -1
                self._start(run, ended)
                active, recorded = self._active(run)
        return self._collect(results, run.recorder)

    def _active(self, run: _Run) -> tuple[np.ndarray | None, np.ndarray]:
        """The running slots as the batch's ids (None: every simulation, the batch's fast path),
        and the running slots whose episode is recorded (both change only when episodes start or
        end)."""
        running = np.flatnonzero(run.running)
        ids = None if len(running) == self.batch else running.astype(np.int32)
        return ids, running[run.recording[running]]

    def _start(self, run: _Run, slots: Iterable[int]) -> None:
        """Spawn the next jobs into free `slots`; slots left without a job stay idle."""
        started: list[int] = []
        for i in slots:
            job = next(run.jobs, None)
            if job is None:
                break
            index, params, seed, terrain, record = job
            field = self._fields[terrain]
            self._slot_model[i] = field.model
            spawn(
                field.model,
                self._spawn_data,
                field.ground,
                self.agent,
                self.layout,
                np.random.default_rng(seed),
            )
            mujoco.mj_getState(field.model, self._spawn_data, self._sims.state[i], _INTEGRATION)
            self._params[i] = params
            run.episode[i], run.running[i], run.returns[i] = index, True, 0.0
            run.recording[i] = record
            if record and run.recorder is None:
                run.recorder = _Recorder()
            started.append(i)
        if not started:
            return
        ids = np.array(started, dtype=np.int32)  # ascending, as `slots` are
        # Also makes the batch re-read models that set_terrains edited (it reads them when set).
        self._sims.set_models(self._slot_model)
        # The settled states' position and velocity stages (contacts and their sensors), as a
        # step leaves them; the slot's first step starts from them.
        self._sims.forward(ids, stage=_STAGE_VEL)
        width = len(run.running)
        self.task.begin(self._qpos[:width], run.state, ids)
        # Recomputing the observation of every row is cheaper than selecting the new ones.
        self.task.observe(
            self._qpos[:width], self._qvel[:width], self._sensor[:width], self._obs[:width]
        )

    @staticmethod
    def _collect(
        results: list[tuple[int, float, int, bool]], recorder: _Recorder | None
    ) -> tuple[np.ndarray, Episodes]:
        results.sort()
        index = np.array([r[0] for r in results], dtype=np.int64)
        episodes = Episodes(
            np.array([r[1] for r in results], dtype=np.float64),
            np.array([r[2] for r in results], dtype=np.int64),
            np.array([r[3] for r in results], dtype=bool),
            recorder.result() if recorder is not None else None,
        )
        return index, episodes
