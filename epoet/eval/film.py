"""How a video frame looks: a side light, ground coloured by height with contour lines, a free
camera that climbs over hills, and a caption; `Film` renders an env's episode that way. All of it
is visual: the physics never reads it, so the episode is the one evaluation runs.
"""

from __future__ import annotations

from typing import Any

import numpy as np

SUN_ELEVATION = 30.0  # degrees above the horizon: slopes facing the light and facing away differ
SUN_HEADING = -60.0  # degrees from +x the light travels: from the camera's left, across it
CONTOUR = 0.1  # metres of height between the contour lines painted on the ground
CHECKER = 1.0  # metres per side of the faint checker squares (a scale for the eye)
CAMERA_DISTANCE = 1.8  # metres from the torso
CAMERA_AZIMUTH = 45.0  # looking towards +x and +y from behind the walker's right, as `track`
CAMERA_ELEVATION = -20.0  # degrees; steeper when a hill would stand between camera and walker
RAMP = np.array(
    [  # ground colours from the terrain's lowest to its highest point
        [0.25, 0.42, 0.75],  # blue valleys
        [0.20, 0.60, 0.55],
        [0.45, 0.70, 0.30],
        [0.90, 0.78, 0.40],
        [0.95, 0.95, 0.92],  # white peaks
    ]
)


def sun_direction() -> np.ndarray:
    """Unit vector the side light travels along (directional: the same everywhere)."""
    elevation, heading = np.radians(SUN_ELEVATION), np.radians(SUN_HEADING)
    return np.array(
        [
            np.cos(elevation) * np.cos(heading),
            np.cos(elevation) * np.sin(heading),
            -np.sin(elevation),
        ]
    )


def height_texture(heights: np.ndarray, size: float, texels: int) -> np.ndarray:
    """A (texels, texels, 3) uint8 image of a heightfield (metres, `size` metres per side) for
    the 2D texture stretched once over it.

    Colour follows height (RAMP over the terrain's own range), with dark contour lines every
    CONTOUR metres and a faint CHECKER: a side light alone leaves plateaus and gentle slopes
    flat, the colours and lines say how high every spot is. MuJoCo puts a texture's row 0 at +y
    and its column 0 at -x, the heightfield its row 0 at -y: texel centres are sampled
    (bilinearly) between the heightfield's samples accordingly.
    """
    from scipy.ndimage import map_coordinates

    nrow, ncol = heights.shape
    u = (np.arange(texels) + 0.5) / texels  # 0 at -x (columns), at +y (rows)
    rows, cols = np.meshgrid((1.0 - u) * (nrow - 1), u * (ncol - 1), indexing="ij")
    h = map_coordinates(heights, [rows, cols], order=1, mode="nearest")
    low, high = float(h.min()), float(h.max())
    level = (h - low) / max(high - low, 1e-9)
    stops = np.linspace(0.0, 1.0, len(RAMP))
    rgb = np.stack([np.interp(level, stops, RAMP[:, c]) for c in range(3)], axis=-1)
    band = np.floor(h / CONTOUR)
    line = np.zeros(h.shape, dtype=bool)  # the texel next to it is in another band
    line[:, :-1] |= band[:, :-1] != band[:, 1:]
    line[:-1, :] |= band[:-1, :] != band[1:, :]
    rgb[line] *= 0.55
    square = np.floor(u * size / CHECKER).astype(int)
    rgb[(square[:, None] + square[None, :]) % 2 == 1] *= 0.8
    return (np.clip(rgb, 0.0, 1.0) * 255).round().astype(np.uint8)


def caption_text(
    label: str, terrain: str, step: int, steps: int, forward: float, episode_return: float
) -> tuple[str, str]:
    """The caption's two columns (names, values), one line each, for mjr_overlay."""
    names = "run\nterrain\nstep\nforward\nreturn"
    values = f"{label}\n{terrain}\n{step} / {steps}\n{forward:+.2f} m\n{episode_return:.1f}"
    return names, values


class Film:
    """Frames of an env's episode: side-lit, height-coloured ground, a camera that stays above
    the hills, and a caption.

    It renders with its own GL and MuJoCo render contexts (not the env's `render()`, which has no
    caption): the env's model is only read, except the ground's texture data and repeat, which
    are visual. Make it after the env's reset put the terrain in: the context uploads the
    heightfield and the texture painted from it when it is made.
    """

    def __init__(self, env: Any, width: int, height: int) -> None:
        import mujoco

        self.mujoco, self.env, self.size = mujoco, env, (height, width)
        model = env.model
        geom = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "terrain")
        material = model.geom_matid[geom]
        texture = model.mat_texid[material, mujoco.mjtTextureRole.mjTEXROLE_RGB]
        texels = int(model.tex_width[texture])
        assert texels == model.tex_height[texture] and model.tex_nchannel[texture] == 3
        start = model.tex_adr[texture]
        model.tex_data[start : start + texels * texels * 3] = height_texture(
            env.ground.heights, 2 * env.ground.half_x, texels
        ).ravel()
        model.mat_texrepeat[material] = 1.0  # once over the whole heightfield
        model.mat_texuniform[material] = False
        vis = model.vis.global_  # the offscreen buffer must hold the frame
        vis.offwidth, vis.offheight = max(vis.offwidth, width), max(vis.offheight, height)
        self.gl = mujoco.GLContext(width, height)
        self.gl.make_current()
        font = (
            mujoco.mjtFontScale.mjFONTSCALE_100
            if height < 400
            else mujoco.mjtFontScale.mjFONTSCALE_150
        )
        self.context = mujoco.MjrContext(model, font)
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self.context)
        self.scene = mujoco.MjvScene(model, maxgeom=1000)
        self.option, self.perturb = mujoco.MjvOption(), mujoco.MjvPerturb()
        self.camera = mujoco.MjvCamera()
        self.camera.type = mujoco.mjtCamera.mjCAMERA_FREE
        self.camera.distance, self.camera.azimuth = CAMERA_DISTANCE, CAMERA_AZIMUTH
        self.camera.elevation = CAMERA_ELEVATION
        self.torso = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "torso")
        self.rect = mujoco.MjrRect(0, 0, width, height)
        self.pixels = np.empty((height, width, 3), dtype=np.uint8)

    def _aim(self) -> None:
        """Look at the torso from the camera's azimuth, as low as the ground lets the line of
        sight pass 0.15 m above it (a camera inside a hill sees its back faces: nothing).

        The camera drops back towards CAMERA_ELEVATION slowly and climbs at once."""
        lookat = self.env.data.xpos[self.torso]
        ground = self.env.ground
        azimuth = np.radians(CAMERA_AZIMUTH)
        along = np.linspace(0.25, 1.0, 12)[:, None]  # near the torso the ground is close anyway
        needed = -85.0
        for elevation in np.arange(CAMERA_ELEVATION, -85.0, -5.0):
            e = np.radians(elevation)
            back = CAMERA_DISTANCE * np.array(
                [-np.cos(e) * np.cos(azimuth), -np.cos(e) * np.sin(azimuth), -np.sin(e)]
            )
            points = lookat + along * back
            rows, cols = ground.cell(points[:, 0], points[:, 1])
            if np.all(points[:, 2] > ground.heights[rows, cols] + 0.15):
                needed = float(elevation)
                break
        current = self.camera.elevation
        self.camera.elevation = needed if needed < current else current + 0.05 * (needed - current)
        self.camera.lookat[:] = lookat

    def _light(self) -> None:
        """The model's overhead light becomes a low side light; the headlight (which shines
        from the camera and flattens what it sees) mostly ambient. No shadows (module
        docstring)."""
        sun = sun_direction()
        for light in self.scene.lights[: self.scene.nlight]:
            light.castshadow = 0
            if light.headlight:
                light.ambient[:], light.diffuse[:], light.specular[:] = 0.35, 0.15, 0.0
            else:
                light.dir[:], light.pos[:] = sun, -10.0 * sun
                light.ambient[:], light.diffuse[:], light.specular[:] = 0.0, 0.75, 0.1

    def frame(self, caption: tuple[str, str]) -> np.ndarray:
        """The current state as an (height, width, 3) uint8 image, the caption at the top left."""
        mujoco = self.mujoco
        self.gl.make_current()
        self._aim()
        mujoco.mjv_updateScene(
            self.env.model,
            self.env.data,
            self.option,
            self.perturb,
            self.camera,
            mujoco.mjtCatBit.mjCAT_ALL,
            self.scene,
        )
        self._light()
        mujoco.mjr_render(self.rect, self.scene, self.context)
        mujoco.mjr_overlay(
            mujoco.mjtFont.mjFONT_NORMAL,
            mujoco.mjtGridPos.mjGRID_TOPLEFT,
            self.rect,
            caption[0],
            caption[1],
            self.context,
        )
        mujoco.mjr_readPixels(self.pixels, None, self.rect, self.context)
        return np.flipud(self.pixels).copy()  # OpenGL's rows run bottom-up

    def close(self) -> None:
        self.context.free()
        self.gl.free()
