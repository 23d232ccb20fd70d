"""The RL baselines (PPO, SAC, VMPO) end to end: Hydra config -> epoet.run.run -> MLflow.

Everything is real (TorchRL collectors, losses and replay buffers, the MuJoCo env, an MLflow
sqlite store in tmp_path); sizes are tiny: 30-step episodes, batches of 60 frames, small grids.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from hydra.errors import ConfigCompositionException
from mlflow import MlflowClient
from omegaconf import DictConfig
from torchrl.envs import ExplorationType
from torchrl.envs.utils import set_exploration_type

from conftest import TINY_BASELINE, tiny_baseline
from epoet.config import compose as compose_config
from epoet.config import validate
from epoet.core.algorithm import Family
from epoet.core.checkpoint import CheckpointError, load_checkpoint
from epoet.core.schema import ConfigError
from epoet.registry import names
from epoet.rl.candidates import CANDIDATES
from epoet.rl.env import RunningObsNorm, make_env, obs_norm_of, terrain_env
from epoet.rl.harness import batch_plan
from epoet.rollout.agent_files import LAST_POLICY
from epoet.rollout.selection import CHOICE_FILE, LAST
from epoet.rollout.torch_policy import load_policy
from epoet.run import run
from epoet.sac import train as sac
from epoet.tracking import MlflowTracker

TINY = [*TINY_BASELINE, "evaluate=false"]

# metrics each algorithm must report besides the loop's own
ALGO_METRICS = {
    "ppo": ["train/loss_objective", "train/loss_critic", "train/entropy", "train/kl_approx"],
    "sac": ["train/loss_actor", "train/loss_qvalue", "train/alpha", "train/entropy"],
    "vmpo": ["train/loss_policy", "train/eta", "train/alpha", "train/kl", "train/entropy"],
}


@pytest.fixture
def store(mlflow_uri: str) -> MlflowClient:
    return MlflowClient(mlflow_uri)


def deterministic_rollout(raw: DictConfig, actor, checkpoint: dict, steps: int = 30):
    """A deterministic-policy rollout on a fresh env normalising as the trained policy does."""
    cfg = validate(raw)
    env = make_env(cfg, obs_norm=cfg.algo.obs_norm, seed=123)
    if cfg.algo.obs_norm:
        RunningObsNorm(obs_norm_of(env)).load_state_dict(checkpoint["obs_norm"])
    with set_exploration_type(ExplorationType.DETERMINISTIC), torch.no_grad():
        td = env.rollout(steps, actor, break_when_any_done=False)
    env.close()
    return td


@pytest.mark.parametrize("algo", names(Family.BASELINE))
def test_smoke_run_logs_to_mlflow_and_exports_a_rebuildable_policy(algo, store, tmp_path):
    raw = compose_config([*tiny_baseline(algo), "evaluate=false"])
    result = run(raw, tmp_path / "run")

    assert result.frames == 240 and result.batches == 4
    (mlflow_run,) = store.search_runs([store.get_experiment_by_name("epoet").experiment_id])
    assert mlflow_run.info.status == "FINISHED"
    assert mlflow_run.data.tags["algo"] == algo and mlflow_run.data.tags["terrain"] == "bowl"
    metrics = mlflow_run.data.metrics
    for key in [
        "train/episode_return",
        "train/episode_length",
        "train/finish_rate",
        "eval/return_mean",
        "eval/finish_rate",
        "final/return_mean",
        "frames",
        "fps",
        *ALGO_METRICS[algo],
    ]:
        assert key in metrics, key
    assert metrics["frames"] == 240
    assert [
        m.step for m in store.get_metric_history(mlflow_run.info.run_id, "eval/return_mean")
    ] == [0, 120, 240]
    assert "policy.pt" in {a.path for a in store.list_artifacts(mlflow_run.info.run_id)}

    # the run's last policy, rebuilt with plain torch, acts as the trained actor; the exported
    # one is the policy the run chose (`selection`), kept from its evaluation point
    choice = json.loads((tmp_path / "run" / CHOICE_FILE).read_text())
    last = result.policy_path
    if choice["exported"] != LAST:
        kept = tmp_path / "run" / CANDIDATES / f"{choice['exported']}.pt"
        assert result.policy_path.read_bytes() == kept.read_bytes()
        last = tmp_path / "run" / LAST_POLICY
    checkpoint = load_checkpoint(tmp_path / "run")
    td = deterministic_rollout(raw, result.learner.actor, checkpoint)
    act = load_policy(last)
    actions = td["action"].numpy()
    assert actions.std(0).max() > 1e-3  # the check below compares actions that vary
    np.testing.assert_allclose(act(td["observation"].numpy()), actions, atol=1e-5)
    np.testing.assert_allclose(act(td["observation"][0].numpy()), actions[0], atol=1e-5)


class Killed(Exception):
    """Stands for the process being killed mid-run."""


@pytest.mark.parametrize("algo", names(Family.BASELINE))
def test_resume_continues_exactly_like_an_uninterrupted_run(algo, store, tmp_path, monkeypatch):
    overrides = [*tiny_baseline(algo), "evaluate=false"]
    straight = run(compose_config(overrides), tmp_path / "straight")

    # kill the second run while it learns from batch 3 (its last checkpoint is after batch 2)
    learner_type = type(straight.learner)
    learn, calls = learner_type.learn, []

    def dying_learn(self, batch, *args):
        calls.append(1)
        if len(calls) == 3:
            raise Killed()
        return learn(self, batch, *args)

    monkeypatch.setattr(learner_type, "learn", dying_learn)
    with pytest.raises(Killed):
        run(compose_config(overrides), tmp_path / "killed")
    monkeypatch.setattr(learner_type, "learn", learn)
    assert load_checkpoint(tmp_path / "killed")["loop"]["batches"] == 2
    resumed = run(
        compose_config([*overrides, f"resume={tmp_path / 'killed'}"]), tmp_path / "killed"
    )

    assert resumed.frames == straight.frames == 240
    ours, theirs = resumed.learner.loss.state_dict(), straight.learner.loss.state_dict()
    assert ours.keys() == theirs.keys()
    for key in ours:
        assert torch.equal(ours[key], theirs[key]), key
    a, b = torch.load(resumed.policy_path), torch.load(straight.policy_path)
    for key in ("obs_loc", "obs_scale"):
        assert (a[key] is None and b[key] is None) or torch.equal(a[key], b[key])
    # one MLflow run, continued: its frame counter went on from the checkpoint to the end
    runs = store.search_runs(
        [store.get_experiment_by_name("epoet").experiment_id],
        order_by=["attributes.start_time ASC"],
    )
    assert len(runs) == 2
    killed_run = runs[1]  # the straight run started first
    assert killed_run.info.status == "FINISHED"
    frames = [m.step for m in store.get_metric_history(killed_run.info.run_id, "frames")]
    assert max(frames) == 240 and frames.count(180) == 1


def test_sac_learns_on_flat_terrain(store, tmp_path):
    """The deterministic evaluation return on flat ground rises clearly above the untrained
    policy's within 6000 frames (~45 s). Short 50-step episodes, gamma 0.9, one update per frame
    and a small initial temperature make the signal -- walking forward, keeping straight -- quick
    to learn; seeds 1, 2, 3 gave final returns 15.5, 23.9, 13.0 against initial -1.0, 1.0, 0.8.
    """
    raw = compose_config(
        [
            "algo=sac",
            "budget=smoke",
            "workers.num=1",
            "terrain.grid=40",
            "seed=1",
            "terrain.max_height=0",
            "terrain.max_height_step=0",
            "agent.spawn_yaw=0",
            "budget.episode_steps=50",
            "budget.frames=6000",
            "budget.eval_every=6000",
            "budget.eval_episodes=5",
            "algo.frames_per_batch=500",
            "algo.updates_per_batch=500",
            "algo.init_random_frames=500",
            "algo.hidden=[64,64]",
            "algo.batch_size=128",
            "algo.gamma=0.9",
            "algo.alpha_init=0.05",
        ]
    )
    with MlflowTracker(None, "sac-flat") as tracker:
        run_id = tracker.start("sac-flat")
        sac.train(validate(raw), tracker, tmp_path, None)
    returns = sorted(
        (m.step, m.value) for m in store.get_metric_history(run_id, "eval/return_mean")
    )
    (_, before), (_, after) = returns
    assert after > before + 5.0, returns


@pytest.mark.parametrize(
    "overrides, message",
    [
        (["algo=ppo", "algo.clip=-1"], "algo.clip must be > 0"),
        (["algo=sac", "algo.batch_size=0"], "algo.batch_size must be > 0"),
        (["algo=vmpo", "algo.top_fraction=1.5"], "algo.top_fraction must be in (0, 1]"),
        (["algo=ppo", "algo.frames_per_batch=0"], "algo.frames_per_batch must be > 0"),
        (["algo=sac", "algo.activation=sigmoid"], "algo.activation must be one of"),
        (["algo=sac", "algo.buffer_size=10"], "algo.buffer_size (10) must hold at least one batch"),
    ],
)
def test_bad_config_fails_at_start_up(overrides, message, store, tmp_path):
    with pytest.raises(ConfigError) as err:
        run(compose_config(overrides), tmp_path / "run")
    assert message in str(err.value)
    assert not (tmp_path / "run").exists()  # nothing started


def test_unknown_option_fails_at_composition():
    with pytest.raises(ConfigCompositionException, match="algo.clipp"):
        compose_config(["algo=ppo", "algo.clipp=0.1"])


def test_resume_from_another_algorithm_is_refused(store, tmp_path):
    run(
        compose_config([*tiny_baseline("vmpo"), "evaluate=false", "budget.frames=60"]),
        tmp_path / "a",
    )
    with pytest.raises(CheckpointError, match="cannot resume algo=ppo"):
        run(compose_config(["algo=ppo", *TINY, f"resume={tmp_path / 'a'}"]), tmp_path / "b")
    # Refused before the tracker reopened it: the vmpo run stays FINISHED.
    (vmpo,) = store.search_runs([store.get_experiment_by_name("epoet").experiment_id])
    assert vmpo.info.status == "FINISHED"


def test_budget_scales_the_batch_and_keeps_the_ratios():
    cfg = validate(compose_config(["algo=sac", "budget=smoke"]))  # 400 frames < 2000 per batch
    plan = batch_plan(cfg)
    assert (plan.frames_per_batch, plan.batches) == (400, 1)
    assert plan.scaled(cfg.algo.updates_per_batch) == 200  # 1000 per 2000 frames
    cfg = validate(compose_config(["algo=ppo", "budget=laptop"]))
    plan = batch_plan(cfg)
    assert (plan.frames_per_batch, plan.batches, plan.scale) == (2000, 50, 1.0)


def test_running_obs_norm_matches_the_data_and_survives_tiny_spreads():
    """Batched updates equal numpy's mean/std of all data; a feature of spread 1e-3 around 100
    (where float32 E[x^2] - E[x]^2 goes negative) still gets a finite, positive scale."""
    from torchrl.envs import ObservationNorm

    gen = torch.Generator().manual_seed(0)
    data = torch.randn(1000, 3, generator=gen) * torch.tensor([2.0, 1e-3, 0.0]) + torch.tensor(
        [-1.0, 1e2, 5.0]
    )
    norm = ObservationNorm(
        loc=torch.zeros(3), scale=torch.ones(3), in_keys=["observation"], standard_normal=True
    )
    stats = RunningObsNorm(norm)
    for chunk in data.split(137):
        stats.update(chunk)
    ref = data.double().numpy()
    np.testing.assert_allclose(stats.mean.numpy(), ref.mean(0), rtol=1e-12)
    np.testing.assert_allclose(norm.scale.numpy(), np.sqrt(ref.var(0) + 1e-8), rtol=1e-5)
    assert torch.isfinite(norm.scale).all() and (norm.scale > 0).all()
    restored = RunningObsNorm(
        ObservationNorm(
            loc=torch.zeros(3), scale=torch.ones(3), in_keys=["observation"], standard_normal=True
        )
    )
    restored.load_state_dict(stats.state_dict())
    assert torch.equal(restored.transform.loc, norm.loc)
    assert torch.equal(restored.transform.scale, norm.scale)


@pytest.mark.parametrize("terrain, limit", [("bowl", 1.0), ("cppn", 2.2)])
def test_training_env_draws_a_new_terrain_per_episode_on_the_height_schedule(terrain, limit):
    """Baselines train on bowls by default; terrain=cppn gives a fresh random CPPN terrain per
    episode. Either way the maximum height S grows by max_height_step per episode."""
    schedule = ["budget.max_height=0.1", "budget.max_height_step=0.3"]
    raw = compose_config(["algo=ppo", *TINY, f"terrain={terrain}", *schedule])
    env = make_env(validate(raw), obs_norm=True, seed=0)
    seen = []
    for _ in range(4):
        env.reset()
        seen.append(terrain_env(env).terrain)
    env.close()
    assert all(t.kind == terrain for t in seen)
    assert len({t.id for t in seen}) == 4
    # set_seed's reset was episode 0, so the four resets above are episodes 1..4
    assert [t.max_height for t in seen] == pytest.approx(
        [min(0.1 + 0.3 * i, limit) for i in range(1, 5)]
    )
