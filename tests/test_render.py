"""`python -m epoet.eval.render`: a real (short, small) video, its MLflow artifact, one-line errors.

The command runs as a subprocess: MuJoCo picks its OpenGL backend once per process, when first
imported, and this test process may already have imported it without one.
"""

from __future__ import annotations

import functools
import os
import subprocess
import sys
from pathlib import Path

import imageio.v2 as imageio
import numpy as np
import pytest
from mlflow import MlflowClient

from conftest import ES_SIZES, TINY_EPOET, one_terrain_suite
from epoet.config import load
from epoet.eval.render import NO_GL
from epoet.rollout.policy import init_params
from epoet.run import run
from epoet.terrain import make_terrain
from epoet.tracking import MlflowTracker


def render_cli(*args: str, cwd: Path, uri: str | None = None) -> subprocess.CompletedProcess:
    """The command with this environment, but MUJOCO_GL unset (the command chooses it)."""
    env = {k: v for k, v in os.environ.items() if k != "MUJOCO_GL"}
    if uri:
        env["MLFLOW_TRACKING_URI"] = uri
    return subprocess.run(
        [sys.executable, "-m", "epoet.eval.render", *args],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )


@functools.cache
def machine_renders() -> bool:
    """Whether plain MuJoCo renders offscreen here with egl, in a process that imports nothing
    else: on such a machine a command that says it cannot render is a bug, not a reason to skip
    (as when epoet's imports came to import MuJoCo before the command chose its backend)."""
    probe = "import mujoco; mujoco.Renderer(mujoco.MjModel.from_xml_string('<mujoco/>'), 8, 8)"
    env = {**os.environ, "MUJOCO_GL": "egl"}
    return (
        subprocess.run([sys.executable, "-c", probe], env=env, capture_output=True).returncode == 0
    )


def skip_without_gl(proc: subprocess.CompletedProcess | str) -> None:
    """Rendering tests need an offscreen GL backend; the command says when there is none, and
    the test skips only when the machine indeed has none."""
    said = proc if isinstance(proc, str) else proc.stderr if proc.returncode == 2 else ""
    if NO_GL in said:
        assert not machine_renders(), f"the machine renders, the command says not: {said}"
        pytest.skip(f"no offscreen OpenGL backend here: {said.strip()}")


def one_error_line(proc: subprocess.CompletedProcess) -> str:
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), proc.stderr
    return lines[0]


def decoded(path: Path) -> list[np.ndarray]:
    # Iterated, not list()ed: the reader reports an unknown (infinite) frame count.
    with imageio.get_reader(path, format="FFMPEG") as reader:
        return [frame for frame in reader]


@pytest.fixture
def policy(tmp_path: Path) -> Path:
    """An ePOET policy file (untrained: the video's content does not matter here)."""
    path = tmp_path / "my policy.npz"
    np.savez(path, theta=init_params(0, ES_SIZES), layer_sizes=np.array(ES_SIZES))
    return path


@pytest.fixture
def suite(tmp_path: Path) -> Path:
    """A one-terrain suite folder for the paper's 2000-step episodes."""
    return one_terrain_suite(tmp_path / "suite", episode_steps=2000, episode_ratio=2.5)


def test_an_es_policy_on_a_terrain_file_becomes_an_mp4_of_the_episode(policy, tmp_path):
    terrain = make_terrain(load(["algo=epoet"]).terrain, seed=0).save(tmp_path / "cppn0.npz")
    proc = render_cli(
        f"run={policy}", f"terrain={terrain}", "steps=10", "width=96", "height=64", cwd=tmp_path
    )
    skip_without_gl(proc)
    assert proc.returncode == 0, proc.stderr
    # Default name: videos/<run label>_<terrain>.mp4, the label's space made safe.
    video = tmp_path / "videos" / "my_policy_cppn0.mp4"
    frames = decoded(video)
    assert len(frames) == 11  # the start, then one per step
    assert {frame.shape for frame in frames} == {(64, 96, 3)}
    assert frames[0].std() > 0  # a picture, not a blank buffer
    assert [p.name for p in video.parent.iterdir()] == [video.name]  # no temporary file left
    assert "11 frames" in proc.stdout and str(Path("videos") / video.name) in proc.stdout


def test_an_epoet_run_folder_renders(policy, compose, mlflow_uri, tmp_path):
    """Its checkpoint is read before the video (the pickled pool imports MuJoCo): the backend
    is chosen before that read, or MuJoCo starts without one where a policy file renders."""
    run(compose([*TINY_EPOET, "budget.iterations=1"]), tmp_path / "run")
    terrain = make_terrain(load(["algo=epoet"]).terrain, seed=0).save(tmp_path / "cppn0.npz")
    small = [f"terrain={terrain}", "steps=3", "width=96", "height=64"]
    skip_without_gl(render_cli(f"run={policy}", *small, cwd=tmp_path))
    proc = render_cli(f"run={tmp_path / 'run'}", *small, cwd=tmp_path, uri=mlflow_uri)
    assert proc.returncode == 0, proc.stderr
    (video,) = (tmp_path / "videos").glob("epoet*.mp4")
    assert len(decoded(video)) == 4


def test_a_suite_terrain_of_an_mlflow_run_is_logged_to_the_run(policy, suite, tmp_path, mlflow_uri):
    with MlflowTracker(mlflow_uri, "render") as tracker:
        run_id = tracker.start("es-run")
        pool = tmp_path / "policies"
        pool.mkdir()
        policy.rename(pool / "env0.npz")
        tracker.log_artifact(pool, "policies")
    out = tmp_path / "clip.mp4"
    proc = render_cli(
        f"run={run_id}",
        "terrain=bumps",
        f"suite={suite}",
        "steps=5",
        "width=64",
        "height=48",
        f"out={out}",
        cwd=tmp_path,
        uri=mlflow_uri,
    )
    skip_without_gl(proc)
    assert proc.returncode == 0, proc.stderr
    assert len(decoded(out)) == 6
    logged = [f.path for f in MlflowClient(mlflow_uri).list_artifacts(run_id, "videos")]
    assert logged == ["videos/clip.mp4"]


def test_an_unknown_suite_terrain_is_one_line(policy, suite, tmp_path):
    line = one_error_line(
        render_cli(f"run={policy}", "terrain=nope", f"suite={suite}", cwd=tmp_path)
    )
    # The GL check runs before the suite is read: without GL the terrain is never looked up,
    # so there is nothing to check here.
    skip_without_gl(line)
    # the suite it was given (not the shipped one), the name typed and the names it has
    assert f"suite {suite} has no terrain 'nope' (it has bumps .. bumps)" in line
    assert not (tmp_path / "videos").exists()


def test_a_missing_run_file_is_one_line(tmp_path):
    line = one_error_line(
        render_cli(f"run={tmp_path / 'missing.npz'}", "terrain=r0l0", cwd=tmp_path)
    )
    assert "missing.npz" in line


def test_an_odd_frame_size_is_one_line(policy, tmp_path):
    line = one_error_line(render_cli(f"run={policy}", "terrain=r0l0", "width=641", cwd=tmp_path))
    assert "must be even" in line


# Renders the same walker on a flat and on a 0.9 m sine-bump terrain, and the bumps once more
# without a caption, with `Film` as `python -m epoet.eval.render` does; in a subprocess for the GL
# backend (module docstring). Prints NO_GL and exits 2 when there is no backend.
SNAPSHOTS = """
import sys
import numpy as np
from epoet.eval.render import NO_GL, RenderError, open_gl
try:
    open_gl()
except RenderError:
    print(NO_GL, file=sys.stderr)
    sys.exit(2)
from epoet.config import load
from epoet.env_factory import make_terrain_env
from epoet.eval.film import Film, caption_text
from epoet.terrain import Terrain
from epoet.eval.suite import terrain_config_for

cfg = load(["algo=epoet"]).terrain
x = np.linspace(0.0, cfg.size, cfg.grid)
bumps = 0.5 + 0.5 * np.sin(2 * np.pi * x / 3.0)[:, None] * np.sin(2 * np.pi * x / 3.0)[None, :]
frames = {}
for name, heightmap in (("flat", np.zeros((cfg.grid, cfg.grid))), ("bumps", bumps)):
    terrain = Terrain(heightmap, 0.9, cfg.size, "bowl", 0)
    env = make_terrain_env(terrain=terrain_config_for([terrain]))
    env.reset(seed=0, options={"terrain": terrain})
    for key, caption in ((name, caption_text("run", name, 0, 10, 0.0, 0.0)),
                         ("uncaptioned", ("", ""))):
        film = Film(env, 320, 240)  # a new one each: the same camera
        frames[key] = film.frame(caption)
        film.close()
    env.close()
np.savez(sys.argv[1], **frames)
"""


@pytest.fixture(scope="module")
def snapshots(tmp_path_factory) -> dict[str, np.ndarray]:
    out = tmp_path_factory.mktemp("snapshots") / "frames.npz"
    proc = subprocess.run(
        [sys.executable, "-c", SNAPSHOTS, str(out)], capture_output=True, text=True, timeout=300
    )
    skip_without_gl(proc)
    assert proc.returncode == 0, proc.stderr
    with np.load(out) as frames:
        return dict(frames)


def luminance(frame: np.ndarray) -> np.ndarray:
    return frame.astype(float) @ np.array([0.299, 0.587, 0.114])


def test_relief_shows_in_the_frame(snapshots):
    # The ground in front of the camera, below the walker: side light and height colours make
    # a 0.9 m relief vary far more than the flat terrain's faint checker (measured: luminance
    # std 23 vs 7, blue-minus-red spread 57 vs 19; with one colour and the overhead light of
    # before, 8.2 vs 8.3: this fails).
    ground = slice(150, None)
    flat, bumps = snapshots["flat"][ground], snapshots["bumps"][ground]
    assert luminance(bumps).std() > 2 * luminance(flat).std()

    def hue_spread(frame: np.ndarray) -> float:  # blue valleys to sand-coloured tops
        blue_minus_red = frame[..., 2].astype(float) - frame[..., 0]
        return float(np.percentile(blue_minus_red, 95) - np.percentile(blue_minus_red, 5))

    assert hue_spread(bumps) > 2 * hue_spread(flat)


def test_every_frame_has_a_caption(snapshots):
    captioned, bare = snapshots["bumps"].astype(int), snapshots["uncaptioned"].astype(int)
    box = (slice(0, 120), slice(0, 130))  # top left, where mjr_overlay writes five lines
    assert np.abs(captioned[box] - bare[box]).mean() > 10
    # The rest of the picture is the same.
    assert np.array_equal(captioned[125:], bare[125:])
    assert np.array_equal(captioned[:, 135:], bare[:, 135:])


def test_importing_the_command_leaves_the_environment_as_it_was():
    """The command chooses MuJoCo's backend when imported; the processes its importer starts
    later (a test's subprocesses, a sweep's jobs) inherit no MUJOCO_GL or PYOPENGL_PLATFORM."""
    probe = (
        "import os; before = dict(os.environ); import epoet.eval.render; "
        "print(sorted(k for k in ('MUJOCO_GL', 'PYOPENGL_PLATFORM') "
        "if os.environ.get(k) != before.get(k)))"
    )
    env = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "PYOPENGL_PLATFORM")}
    done = subprocess.run(
        [sys.executable, "-c", probe], env=env, capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0 and done.stdout.strip() == "[]", done.stdout + done.stderr
