"""The reference's rendering of a CPPN terrain, as its environment rendered one at every reset:
what the authors' agents trained on (`terrain.rendering=reference`) and what their evaluation
terrains are (`suite=paper`, epoet/eval/reference/convert.py).

docs/reference.md ("Terrain") has the arithmetic; in short, on the 200 x 200 hfield (5 samples
per metre, sample (row r, column c) at reference x = c/5 - 17, y = r/5 - 20):
- the CPPN is read at ((c/5 - 17 - 12) pi/12, (r/5 - 20 - 12) pi/12) for columns c < 120 only,
  its value at sample (110, 110) subtracted from that sample on (a step at row 110);
- every sample, the window included, steps a damped recurrence towards S/2 (velocity = 0.8
  velocity + 0.08 sign(S/2 - z); z += velocity), carried over from row to row, which makes the
  heights beyond the window;
- that field is normalised to [0.2, S], a random bowl (level ~ U(0.5, S + 0.5), a 20 x 20 grid
  of U(0.15, 1) bumps zoomed cubically) to [0, S], mixed 0.3 bowl + 0.7 CPPN and normalised to
  [0, S] again.
The reference drew the bowl from numpy's global generator at each reset; here each terrain
draws it from its own seed, so a terrain is a function of its genome, seed and S.

S: the reference's hfield elevation starts at 1 m and grows 0.001 per reset; its heights, in
[0, S], were then scaled by S again (defect 2), so their relief was S^2. Here the heights are
in [0, 1] and 1 stands for S metres: the relief is S, at every S (docs/fidelity.md). At the
S = 1 m of the paper suite the two agree.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from scipy import ndimage

from epoet.terrain.config import REFERENCE_GRID as GRID
from epoet.terrain.terrain import normalize

PER_METRE = 5  # samples per metre (the reference's get_local_cor)
OFFSET = (17.0, 20.0)  # reference metres from the hfield's first column / row to x = y = 0
WINDOW = 120  # columns read from the CPPN (TERRAIN_STARTPAD)
CENTRE = 12.0  # CPPN input 0 lies 12 m ahead and 12 m to the side
NORM_AT = 110  # the sample whose CPPN value is subtracted from then on
CPPN_FLOOR = 0.2  # the CPPN part is normalised to [0.2, S]
BOWL_WEIGHT = 0.3
BUMPS, BUMP_LOW = 20, 0.15
EVAL_HEIGHT = 1.0  # S at evaluation, metres (module docstring)


def reference_inputs() -> tuple[np.ndarray, np.ndarray]:
    """The CPPN's (x, y) inputs at each sample's reference coordinates, (row, column)."""
    steps = np.arange(GRID) / PER_METRE
    x = (steps - OFFSET[0] - CENTRE) * math.pi / CENTRE
    y = (steps - OFFSET[1] - CENTRE) * math.pi / CENTRE
    xs, ys = np.meshgrid(x, y, indexing="xy")
    return xs, ys


@njit(cache=True)
def _drift(cppn: np.ndarray, height: float) -> np.ndarray:
    """The reference's row-major sweep: the CPPN inside the window, the damped walk beyond."""
    rows, cols = cppn.shape
    half = height / 2.0
    out = np.empty((rows, cols))
    velocity, z, z_norm = 0.0, half, 0.0
    for r in range(rows):
        for c in range(cols):
            velocity = 0.8 * velocity + 0.08 * np.sign(half - z)
            z += velocity
            if c < WINDOW:
                z = half + cppn[r, c]
                if r == NORM_AT and c == NORM_AT:
                    z_norm = cppn[r, c]
                z -= z_norm
            out[r, c] = z
    return out


def cppn_part(cppn: np.ndarray, height: float) -> np.ndarray:
    """The CPPN part of the terrain, in [0.2, S], from the CPPN's values at `reference_inputs`."""
    return normalize(_drift(cppn, height)) * (height - CPPN_FLOOR) + CPPN_FLOOR


def bowl_part(rng: np.random.Generator, height: float) -> np.ndarray:
    """The random bowl times smooth bumps, in [0, S]."""
    level = rng.uniform(0.5, height + 0.5)
    rows, cols = np.ogrid[-1 : 1 : GRID * 1j, -1 : 1 : GRID * 1j]
    radius = np.clip(np.sqrt(cols**2 + rows**2), 0.04, 1.0)
    bowl = level - np.cos(2.0 * np.pi * radius) / 2.0
    bumps = ndimage.zoom(rng.uniform(BUMP_LOW, 1.0, (BUMPS, BUMPS)), GRID / float(BUMPS))
    return normalize(bowl * bumps) * height


def render(cppn: np.ndarray, seed: int, height: float = EVAL_HEIGHT) -> np.ndarray:
    """The terrain's (200, 200) heights in [0, 1], 1 standing for S = `height` metres, from the
    CPPN's values at `reference_inputs` (cppn.py `render_reference` evaluates a genome there)."""
    mixed = BOWL_WEIGHT * bowl_part(np.random.default_rng(seed), height) + (
        1.0 - BOWL_WEIGHT
    ) * cppn_part(cppn, height)
    return normalize(mixed)
