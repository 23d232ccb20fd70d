"""`algo.es.terrain_variants`: an ES step's mirrored pairs spread over renderings of the niche's
genome (epoet/open_ended/service.py `es_requests`, `merge_variants`)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from conftest import serial_loop
from epoet.config import load
from epoet.open_ended.keys import Key
from epoet.open_ended.loop import Epoet
from epoet.rollout.populations import Mirrored, Request

SIZES = (53, 8, 18)


def make_loop(variants: int) -> Epoet:
    cfg = load(["budget=paper", f"algo.es.terrain_variants={variants}"])
    agent = replace(cfg.agent, max_episode_steps=15, settle_steps=2)
    terrain = replace(cfg.terrain, grid=40, max_height=0.3)
    return serial_loop(cfg.algo, agent, terrain, SIZES, seed=5, n_pairs=4)


def test_one_variant_is_the_niches_terrain_alone():
    loop = make_loop(1)
    pair = loop.pool.active[0]
    [request] = loop.service.es_requests(pair.env, 0, pair.theta, pair.es.sample_seeds(), 0.02, 0)
    assert request.terrain is loop.service.terrain(pair.env, 0)


def test_variants_put_each_mirrored_pair_on_one_rendering_of_the_niche_in_the_steps_order():
    loop = make_loop(2)
    service, pair = loop.service, loop.pool.active[0]
    noise = pair.es.sample_seeds()
    requests = service.es_requests(pair.env, 0, pair.theta, noise, 0.02, record=2)
    own, other = (r.terrain for r in requests)
    assert own is service.terrain(pair.env, 0)
    assert other.genome is own.genome and other.max_height == own.max_height
    assert not np.array_equal(other.heightmap, own.heightmap)  # another bowl
    merged = service.merge_variants(service.run(requests))
    n = len(noise)
    assert merged.returns.shape == (2 * n,)
    # pair i = 3 sits in the second variant: its + and - episodes at i and n + i of the step
    spawn = service.seeds(n, Key.ES_SPAWN, pair.env.index, 0)
    alone = service.run([Request(other, Mirrored.of(pair.theta, noise[3:4], 0.02, spawn[3:4]))])[0]
    np.testing.assert_allclose(merged.returns[[3, n + 3]], alone.returns)
    assert merged.transitions is not None and set(merged.transitions["episode"]) == {0, 1}


def test_a_training_step_with_variants_runs_and_stays_deterministic():
    first, second = make_loop(2), make_loop(2)
    for loop in (first, second):
        loop.run_iteration()
    np.testing.assert_array_equal(first.pool.active[0].theta, second.pool.active[0].theta)
