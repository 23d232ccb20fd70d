"""`python -m epoet.eval.render run=<spec> terrain=<suite terrain name | terrain .npz> [seed=0]
[steps=N] [width=640] [height=480] [out=path.mp4]`: one episode of a trained agent as an mp4.

`run` is what `python -m epoet.eval.evaluate` takes (an MLflow run id, a run folder or a policy file);
the agent walks with the episode rules it was trained with (its run's agent config), on a suite
terrain along the suite's course as evaluation runs it, for `steps` steps or its episode length,
from the start `seed` keys. The video plays in real time
(1 / agent.timestep frames per second) from the env's tracking camera, and goes to `out`
(default `videos/<run label>_<terrain>.mp4`) and, for an MLflow run, to its artifacts under
`videos/`.

Rendering is MuJoCo's offscreen OpenGL on the CPU: MUJOCO_GL defaults to `egl`, which Mesa
(packages libegl1, libegl-mesa0, libgl1-mesa-dri) serves with its llvmpipe software rasteriser,
no GPU or display needed; `MUJOCO_GL=osmesa` works too once libosmesa6 is installed. Shadows
are turned off: on llvmpipe MuJoCo's 4096 x 4096 shadow map cut the frame rate 3-8 times and
left acne on the large terrain. Relief shows without them: the light comes low from the side
(slopes facing it bright, facing away dark), the ground is coloured by height with contour lines
every 0.1 m (`height_texture`), and a free camera climbs when a hill would hide the walker.
Every frame carries a caption (run, terrain and its relief, step, forward distance, return so
far) drawn by MuJoCo's own overlay. Writing mp4 needs the `video` extra (imageio,
imageio-ffmpeg).

Bad input (config, run, terrain, suite, store, a missing GL backend or video writer) ends in
one line on stderr and exit code 2, before the episode starts.

Examples:

    python -m epoet.eval.render run=outputs/2026-11-25/10-00-00_epoet_s0 terrain=r1l3
    python -m epoet.eval.render run=reference:poet_hexA8/flat terrain=r0c0 suite=paper
    python -m epoet.eval.render run=policy.pt terrain=gallery/cppn_0.npz steps=500 out=walk.mp4
"""

from __future__ import annotations

import dataclasses
import os
import re
import sys
import tempfile
import time
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import Any

GL_BACKEND = os.environ.get("MUJOCO_GL") or "egl"  # MuJoCo's OpenGL: the user's, else egl


def _import_mujoco() -> None:
    """MuJoCo reads MUJOCO_GL once, when it is first imported, and the imports below import it
    (epoet.cli reads the config schemas, which name the env): it is imported here first, with
    GL_BACKEND. A backend whose libraries are missing fails in that import; MuJoCo is then
    imported with GL off, so the command still reads its input and open_gl says in one line
    what to install. The environment is left as it was: importing this module changes nothing
    for the processes a program (or a test) starts later."""
    before = dict(os.environ)
    os.environ["MUJOCO_GL"] = GL_BACKEND
    try:
        import mujoco  # noqa: F401
    except Exception:  # missing libraries surface as ImportError, AttributeError, ...
        os.environ["MUJOCO_GL"] = "disable"
        import mujoco  # noqa: F401
    finally:  # MUJOCO_GL, and PYOPENGL_PLATFORM that MuJoCo sets for PyOpenGL
        os.environ.clear()
        os.environ.update(before)


_import_mujoco()

from tqdm import tqdm  # noqa: E402

from epoet.cli import KeyValueCommand  # noqa: E402
from epoet.core.cli import fail  # noqa: E402
from epoet.core.schema import ConfigError  # noqa: E402
from epoet.envs.model import TerrainMismatchError  # noqa: E402
from epoet.envs.terrain_env import TerrainEnv  # noqa: E402
from epoet.eval.agents import AgentError, TrainedRun, resolve_run  # noqa: E402
from epoet.eval.config import RenderConfig  # noqa: E402
from epoet.eval.film import Film, caption_text  # noqa: E402
from epoet.eval.reference.files import configure  # noqa: E402
from epoet.eval.suite import SuiteError, load_suite, terrain_config_for  # noqa: E402
from epoet.terrain import Terrain, TerrainFileError  # noqa: E402
from epoet.tracking import TrackingError  # noqa: E402

VIDEOS = "videos"  # the default output folder, and the artifact folder in the MLflow run
NO_GL = "MuJoCo cannot render offscreen"
GL_HELP = (
    "for CPU rendering install Mesa's EGL, `sudo apt-get install libegl1 libegl-mesa0 "
    "libgl1-mesa-dri` (MUJOCO_GL=egl), or OSMesa, `sudo apt-get install libosmesa6` "
    "with MUJOCO_GL=osmesa"
)


class RenderError(RuntimeError):
    """What rendering needs from the machine is missing; one sentence naming the fix."""


COMMAND = KeyValueCommand("render", __doc__, RenderConfig, plain=("terrain",))


def parse_args(argv: list[str]) -> RenderConfig:
    """The validated config of the command line."""
    cfg: RenderConfig = COMMAND.parse(argv)
    if cfg.width % 2 or cfg.height % 2:  # H.264's 4:2:0 chroma halves both sides
        raise ConfigError(
            f"width and height must be even for an mp4, got {cfg.width} x {cfg.height}."
        )
    return cfg


def require_imageio() -> ModuleType:
    """imageio's v2 API (it streams frames to ffmpeg), or RenderError naming the extra."""
    try:
        import imageio.v2 as imageio
        import imageio_ffmpeg

        imageio_ffmpeg.get_ffmpeg_exe()  # the wheel ships ffmpeg; fails if it is missing
    except (ImportError, RuntimeError) as err:
        raise RenderError(
            "writing mp4 needs imageio and imageio-ffmpeg: pip install 'epoet[video]'"
        ) from err
    return imageio


def open_gl() -> str:
    """Prove the chosen backend (GL_BACKEND) renders offscreen; its name. The proof is a tiny
    Renderer, as the env makes: a GL context alone can "succeed" without a display (glfw)."""
    try:
        import mujoco

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # glfw warns, then the Renderer fails: one line
            mujoco.Renderer(mujoco.MjModel.from_xml_string("<mujoco/>"), 16, 16).close()
    except Exception as err:  # missing libraries surface as ImportError, AttributeError, ...
        raise RenderError(f"{NO_GL} with MUJOCO_GL={GL_BACKEND}; {GL_HELP}") from err
    return GL_BACKEND


def load_terrain(spec: str, suite: str | None) -> tuple[Any, str, Any]:
    """A terrain file (`.npz`) or a suite terrain's name; with the name the video carries, and
    the suite's course for a suite terrain (None for a file: the run's own course)."""
    if spec.endswith(".npz") or Path(spec).is_file():
        return Terrain.load(spec), Path(spec).stem, None
    loaded = load_suite(suite)
    return loaded.by_name(spec), spec, loaded.course


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "_", text).strip("_") or "agent"


@contextmanager
def video_writer(path: Path, fps: float, imageio: ModuleType) -> Iterator[Any]:
    """An mp4 writer whose file appears at `path` only when complete.

    ffmpeg writes a temporary file in the same folder (it picks the container from the
    `.mp4` suffix), renamed over `path` when the writer closes; on any failure it is removed.
    """
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.stem}.", suffix=".mp4")
    except OSError as err:  # name the output, not the temporary file
        raise OSError(f"cannot write {path}: {err.strerror or err}.") from None
    os.fchmod(fd, 0o644)  # mkstemp makes 0600; a video is as readable as any other output
    os.close(fd)
    try:
        # macro_block_size=2 keeps the frame size (the default 16 would resize e.g. 100 x 60).
        with imageio.get_writer(
            tmp,
            format="FFMPEG",
            fps=fps,
            codec="libx264",
            macro_block_size=2,
            ffmpeg_log_level="error",
        ) as writer:
            yield writer
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


@dataclass(frozen=True)
class Video:
    """What `record` wrote, for the summary line."""

    path: Path
    frames: int
    fps: float
    episode_return: float
    finished: bool
    render_fps: float  # frames simulated, rendered and encoded per second of wall time

    def summary(self) -> str:
        return (
            f"{self.frames} frames ({self.frames / self.fps:.1f} s at {self.fps:g} fps, "
            f"rendered at {self.render_fps:.1f} frames/s), return "
            f"{self.episode_return:.1f}, finished {self.finished}: {self.path}"
        )


def record(
    cfg: RenderConfig, run: TrainedRun, terrain: Any, name: str, course: Any, imageio: ModuleType
) -> Video:
    """One episode of the run's agent on the terrain (on `course`, as evaluation runs it, when
    it is a suite terrain), every frame (captioned, see `Film`) into the mp4."""
    agent = run.agent_config(cfg.agent)
    if course is not None:
        agent = course.rules(agent)
    if cfg.steps is not None:
        agent = dataclasses.replace(agent, max_episode_steps=cfg.steps)
    path = Path(cfg.out) if cfg.out else Path(VIDEOS) / f"{_slug(run.label)}_{_slug(name)}.mp4"
    env = TerrainEnv(agent=agent, terrain=terrain_config_for([terrain]))
    policy = run.agent.load()
    fps = 1.0 / agent.timestep
    steps = agent.max_episode_steps
    where = f"{name} ({terrain.max_height:g} m relief)"
    film: Film | None = None
    start = time.perf_counter()
    try:
        with video_writer(path, fps, imageio) as writer:
            obs, info = env.reset(seed=cfg.seed, options={"terrain": terrain})
            film = Film(env, cfg.width, cfg.height)  # after reset: the terrain is in
            start_x, total, step, done = info["x"], 0.0, 0, False
            writer.append_data(film.frame(caption_text(run.label, where, 0, steps, 0.0, 0.0)))
            with tqdm(
                total=steps, unit="step", file=sys.stdout, desc=f"{run.label} on {name}"
            ) as bar:
                while not done:
                    obs, reward, terminated, truncated, info = env.step(policy(obs))
                    total, step, done = total + reward, step + 1, terminated or truncated
                    writer.append_data(
                        film.frame(
                            caption_text(run.label, where, step, steps, info["x"] - start_x, total)
                        )
                    )
                    bar.update()
    finally:
        if film is not None:
            film.close()
        env.close()
    return Video(
        path, step + 1, fps, total, info["finished"], (step + 1) / (time.perf_counter() - start)
    )


def main(argv: list[str] | None = None) -> None:
    """CLI: bad input ends in one line and exit code 2; Ctrl-C leaves no partial video."""
    try:
        cfg = parse_args(sys.argv[1:] if argv is None else argv)
        imageio = require_imageio()
        assert cfg.run is not None and cfg.terrain is not None  # required: RenderConfig checks
        configure(cfg.epoet_3d)
        run = resolve_run(cfg.run, cfg.tracking.uri)  # checked before GL is proven
        run.agent_config(cfg.agent)  # the robot the policy was trained on: checked before GL
        open_gl()
    except (
        ConfigError,
        RenderError,
        AgentError,
        OSError,
    ) as err:
        fail(err)
    try:
        terrain, name, course = load_terrain(cfg.terrain, cfg.suite)
        video = record(cfg, run, terrain, name, course, imageio)
        print(video.summary(), flush=True)  # before logging: the video exists whatever follows
        if run.stored is not None:
            run.stored.log_results({}, artifacts={video.path: VIDEOS})
            print(f"  logged to MLflow run {run.run_id} under {VIDEOS}/")
            print(f"  runs:     {run.stored.ui_hint()}")
    except (
        SuiteError,
        TerrainFileError,
        TerrainMismatchError,
        TrackingError,
        AgentError,
        OSError,
    ) as err:  # AgentError: the policy file changed since resolve_run checked it
        fail(err)
    except KeyboardInterrupt:
        print("interrupted (an unfinished video is removed)", file=sys.stderr)
        sys.exit(130)


if __name__ == "__main__":
    main()
