"""`python -m epoet.eval.gallery terrain=cppn n=8 out=DIR`: a root terrain and its descendants as a PNG.

Writes DIR/gallery.png (a chain: each panel is a mutated child of the previous one, at
iterations 0, 25, 50, ... so S grows by the schedule) and each terrain's npz in DIR. A kind that
does not evolve (terrain=bowl) has nothing to mutate: the panels are fresh terrains of it along
the same schedule.
Bad values end with one line on stderr and exit status 2.

Examples:

    python -m epoet.eval.gallery
    python -m epoet.eval.gallery terrain=cppn n=12 seed=3 out=gallery/seed3
    python -m epoet.eval.gallery terrain=bowl n=4 out=gallery/bowls
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from epoet.cli import KeyValueCommand
from epoet.core.cli import fail
from epoet.core.schema import ConfigError
from epoet.eval.config import GalleryConfig
from epoet.terrain.config import MutationError, generator_for
from epoet.terrain.generate import make_terrain, mutate_terrain
from epoet.terrain.terrain import Terrain, plot_terrain

ITERATION_STEP = 25  # iterations between panels: S grows by 25 * max_height_step per panel
COLUMNS = 4


def chain(cfg: GalleryConfig) -> list[Terrain]:
    """Root terrain, then each panel a child of the previous one, seeds derived from cfg.seed."""
    seeds = [int(s) for s in np.random.SeedSequence(cfg.seed).generate_state(cfg.n)]
    terrains = [make_terrain(cfg.terrain, seeds[0], iteration=0)]
    for k in range(1, cfg.n):
        if generator_for(cfg.terrain.kind).evolves:
            terrains.append(
                mutate_terrain(terrains[-1], cfg.terrain, seeds[k], iteration=k * ITERATION_STEP)
            )
        else:
            terrains.append(make_terrain(cfg.terrain, seeds[k], iteration=k * ITERATION_STEP))
    return terrains


def write_gallery(terrains: list[Terrain], out: Path) -> Path:
    """One 3D panel per terrain on a shared height axis, so the growing relief is visible."""
    rows, cols = math.ceil(len(terrains) / COLUMNS), min(len(terrains), COLUMNS)
    fig = Figure(figsize=(4.2 * cols, 3.8 * rows), dpi=100)
    zmax = max(t.max_height for t in terrains)
    for k, terrain in enumerate(terrains):
        plot_terrain(fig.add_subplot(rows, cols, k + 1, projection="3d"), terrain, zmax=zmax)
    top = 1.0 - 0.45 / fig.get_figheight()  # room for the two-line titles, whatever the rows
    fig.subplots_adjust(left=0.02, right=0.98, bottom=0.03, top=top, wspace=0.05, hspace=0.15)
    path = out / "gallery.png"
    fig.savefig(path)
    return path


COMMAND = KeyValueCommand("gallery", __doc__, GalleryConfig)


def main(argv: list[str] | None = None) -> None:
    cfg: GalleryConfig = COMMAND.parse(argv)
    try:
        out = Path(cfg.out)
        out.mkdir(parents=True, exist_ok=True)
        terrains = chain(cfg)
        for terrain in terrains:
            terrain.save(out / f"{terrain.id}.npz")
        png = write_gallery(terrains, out)
        print(f"wrote {png} and {len(terrains)} terrain files to {out}/")
    except (ConfigError, MutationError, OSError) as err:
        fail(err)


if __name__ == "__main__":
    main()
