"""Every agent file the repository commits under docs/results/ runs, evaluated bare (`evaluate
run=<file>`), with the physics integrator its record's run trained with (pipeline.stamp)."""

from __future__ import annotations

from functools import cache
from pathlib import Path

import pytest

from epoet.config import compose, validate
from epoet.eval.agents import resolve_run
from epoet.eval.evaluate import COMMAND  # registers the evaluate command's schema
from pipeline.stamp import agent_files, record_config, record_integrator

RESULTS = Path(__file__).resolve().parent.parent / "docs" / "results"


@cache
def evaluation_agent(robot: str):
    """`evaluate run=<file> agent=<robot>`'s default agent config, as a user types it."""
    return validate(compose(["run=any.npz", f"agent={robot}"], config_name=COMMAND.name)).agent


FILES = [p for p in agent_files(RESULTS) if record_integrator(p, RESULTS) is not None]


def test_the_records_hold_agent_files():
    assert len(FILES) > 100  # the success-against-compute and robot records


@pytest.mark.parametrize("path", FILES, ids=lambda p: str(p.relative_to(RESULTS)))
def test_a_committed_agent_file_runs_bare_with_its_records_integrator(path):
    defaults = evaluation_agent(record_config(path, RESULTS)["agent"]["name"])
    run = resolve_run(str(path))
    assert run.config is None  # bare: nothing but the file
    assert run.agent_config(defaults).integrator == record_integrator(path, RESULTS)
