"""Settings compared on one suite (analysis.levers), read from committed records: a setting's
row is its seeds' exported agents, as docs/RESULTS.md reports them, and the paired difference is
seed against seed."""

from __future__ import annotations

from pathlib import Path

import pytest

from analysis.levers import main, readings
from analysis.records import RUN_FILE, read_json
from analysis.store import AnalysisError

RESULTS = Path(__file__).resolve().parent.parent / "docs" / "results"
LEVERS = RESULTS / "levers"


def test_a_setting_reads_as_its_seeds_and_pairs_seed_with_seed(capsys) -> None:
    args = ["--base", str(LEVERS / "reference"), "--records", str(LEVERS / "variants4")]
    assert main([*args, "--suite", "paper"]) == 0
    rows = {
        tuple(cell.strip() for cell in line.split("|")[1:3]): line
        for line in capsys.readouterr().out.splitlines()[2:]
    }
    # RESULTS' "Terrain variation over 3 seeds" at 60 minutes, read by another path there
    row = rows[("variants4", "60")]
    assert "| 60.0 / 49.4 / 54.4 | 54.6 % [41.4, 67.8] | 63.8 % |" in row
    # against the reference rendering's 64.375 / 51.875 / 51.25: -4.375, -2.5, +3.125
    assert float(row.split("|")[-2].split()[0]) == pytest.approx(-1.25, abs=0.051)
    assert rows[("reference", "60")].endswith("|  |")  # the base is not paired with itself


def test_a_folder_without_the_algorithms_records_is_one_line(tmp_path: Path, capsys) -> None:
    assert main(["--base", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "holds no records of epoet" in err[0]
    with pytest.raises(AnalysisError):
        readings(tmp_path, "paper", "ppo")


def test_a_folder_of_several_algorithms_reads_only_the_asked_ones_records() -> None:
    """docs/results/compute holds ePOET's and ePOET-SAC's records, both evaluated on the shipped
    suite: ePOET's readings are its own records' (`epoet_s*` also names epoet_sac_s*)."""
    found = readings(RESULTS / "compute", "shipped", "epoet")
    for mark, seeds in found.items():
        for seed, (success, _) in seeds.items():
            info = read_json(RESULTS / "compute" / f"epoet_s{seed}" / RUN_FILE)
            assert success == info["snapshots"][mark]["evaluations"]["shipped"]["success_rate"]
    assert sorted(found["60"]) == [1, 2, 3]
