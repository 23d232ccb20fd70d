"""Bad agent files through the real commands (`python -m epoet.eval.evaluate` and `epoet.eval.render`):
each is one `error:` line on stderr and exit 2, before any episode, with nothing written to the
MLflow store; an agent acting non-finite is a failed episode and one warning line, not a crash.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch

from conftest import ACT_DIM, ES_SIZES, OBS_DIM, one_terrain_suite
from epoet.rl.policy_file import POLICY_FORMAT
from epoet.rollout.policy import init_params, num_params
from test_render import one_error_line, render_cli


def evaluate_cli(*args: str, cwd: Path, uri: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "epoet.eval.evaluate", *args],
        cwd=cwd,
        env={**os.environ, "MLFLOW_TRACKING_URI": uri},
        capture_output=True,
        text=True,
        timeout=300,
    )


def es_file(
    path: Path, theta: np.ndarray | None = None, sizes: tuple[int, ...] | None = ES_SIZES
) -> Path:
    arrays = {} if theta is None else {"theta": theta}
    if sizes is not None:
        arrays["layer_sizes"] = np.array(sizes)
    np.savez(path, **arrays)
    return path


def torch_file(
    path: Path, hidden: list[int], weights: dict[str, torch.Tensor], act_dim: int = ACT_DIM
) -> Path:
    """A policy.pt in epoet.rl.policy_file's format (ReLU, no normaliser)."""
    torch.save(
        {
            "format": POLICY_FORMAT,
            "obs_dim": OBS_DIM,
            "act_dim": act_dim,
            "hidden": hidden,
            "activation": "relu",
            "obs_loc": None,
            "obs_scale": None,
            "obs_clip": None,
            "state_dict": weights,
        },
        path,
    )
    return path


CASES = [
    "random bytes .npz",
    "random bytes .pt",
    "other torch file",
    "no layer_sizes",
    "no theta",
    "wrong input size",
    "theta length",
    "NaN theta",
    "inf theta",
    "torch wrong action size",
    "torch NaN weight",
]


def bad_files(tmp: Path) -> dict[str, tuple[Path, str]]:
    """(file, words its error names) for each kind of bad file."""
    nan_theta = init_params(0, ES_SIZES)
    nan_theta[7] = np.nan
    inf_theta = init_params(0, ES_SIZES)
    inf_theta[-1] = np.inf
    (tmp / "random.npz").write_bytes(np.random.default_rng(0).bytes(500))
    (tmp / "random.pt").write_bytes(np.random.default_rng(1).bytes(500))
    torch.save({"weights": torch.zeros(3)}, tmp / "other.pt")
    return {
        "random bytes .npz": (tmp / "random.npz", "not a readable .npz"),
        "random bytes .pt": (tmp / "random.pt", "not a readable torch file"),
        "other torch file": (tmp / "other.pt", "is not an epoet policy"),
        "no layer_sizes": (
            es_file(tmp / "no_sizes.npz", init_params(0, ES_SIZES), None),
            "has no layer_sizes",
        ),
        "no theta": (es_file(tmp / "no_theta.npz"), "has no theta"),
        "wrong input size": (
            es_file(tmp / "wrong_in.npz", init_params(0, (10, 64, 18)), (10, 64, 18)),
            f"the hexapod has {OBS_DIM} observations",
        ),
        "theta length": (
            es_file(tmp / "short.npz", init_params(0, ES_SIZES)[:-5]),
            f"take {num_params(ES_SIZES)} numbers",
        ),
        "NaN theta": (es_file(tmp / "nan.npz", nan_theta), "non-finite"),
        "inf theta": (es_file(tmp / "inf.npz", inf_theta), "non-finite"),
        "torch wrong action size": (
            torch_file(
                tmp / "act5.pt",
                [],
                {"0.weight": torch.zeros(5, OBS_DIM), "0.bias": torch.zeros(5)},
                act_dim=5,
            ),
            "to 5 actions",
        ),
        "torch NaN weight": (
            torch_file(
                tmp / "nan.pt",
                [],
                {
                    "0.weight": torch.full((ACT_DIM, OBS_DIM), np.nan),
                    "0.bias": torch.zeros(ACT_DIM),
                },
            ),
            "non-finite",
        ),
    }


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, tuple[Path, str]]:
    return bad_files(tmp_path_factory.mktemp("bad_agents"))


def assert_nothing_written(cwd: Path, store: Path) -> None:
    assert not (store / "mlflow.db").exists() and not (cwd / "mlflow.db").exists()
    assert not (cwd / "mlruns").exists() and not (cwd / "evaluation").exists()
    assert not (cwd / "videos").exists()


@pytest.mark.parametrize("command", ["evaluate", "render"])
@pytest.mark.parametrize("case", CASES)
def test_a_bad_agent_file_is_one_line_exit_2_and_writes_nothing(
    files, case, command, tmp_path
) -> None:
    path, words = files[case]
    store = tmp_path / "store"
    store.mkdir()
    uri = f"sqlite:///{store}/mlflow.db"
    if command == "evaluate":
        proc = evaluate_cli(f"run={path}", "episodes=1", "processes=1", cwd=tmp_path, uri=uri)
    else:
        proc = render_cli(f"run={path}", "terrain=r0l0", "steps=2", cwd=tmp_path, uri=uri)
    line = one_error_line(proc)
    assert str(path) in line and words in line, line
    assert "Traceback" not in proc.stderr + proc.stdout
    assert_nothing_written(tmp_path, store)


@pytest.fixture
def short_suite(tmp_path: Path) -> Path:
    """A one-terrain suite with 40-step episodes."""
    return one_terrain_suite(tmp_path / "suite", episode_steps=40, episode_ratio=1.0)


def overflowing_policy(path: Path) -> Path:
    """Finite ES parameters whose actions turn NaN: one layer of +-1e308 weights, so once two
    observations exceed 1 in size (joint velocities soon do) their terms are +inf and -inf."""
    sizes = (OBS_DIM, ACT_DIM)
    signs = np.random.default_rng(0).choice([-1.0, 1.0], num_params(sizes))
    return es_file(path, 1e308 * signs, sizes)


def test_non_finite_actions_are_a_failed_episode_and_one_warning(short_suite, tmp_path) -> None:
    policy = overflowing_policy(tmp_path / "overflow.npz")
    out = tmp_path / "results"
    proc = evaluate_cli(
        f"run={policy}",
        f"suite={short_suite}",
        "episodes=2",
        "processes=1",
        f"out={out}",
        cwd=tmp_path,
        uri=f"sqlite:///{tmp_path}/mlflow.db",
    )
    assert proc.returncode == 0, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("warning: ") and "non-finite" in lines[0], (
        proc.stderr
    )
    assert "2 episodes" in lines[0] and "bumps episode 0" in lines[0]
    episodes = pd.read_csv(out / "episodes.csv")
    assert len(episodes) == 2 and not episodes.solved.any() and not episodes.finished.any()
    assert np.isfinite(episodes["return"]).all() and (episodes.length < 40).all()
    with np.load(out / "actions.npz") as actions:
        assert np.isfinite(actions["action"]).all()
    assert not (tmp_path / "mlflow.db").exists()  # a policy file has no run to log to
