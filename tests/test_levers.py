"""Settings compared on one suite (analysis.levers), read from committed records: a setting's
row is its seeds' exported agents, as docs/RESULTS.md reports them, and the paired difference is
seed against seed."""

from __future__ import annotations

from pathlib import Path

import pytest

from analysis.levers import main
from analysis.store import AnalysisError

LEVERS = Path(__file__).resolve().parent.parent / "docs" / "results" / "levers"


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
        from analysis.levers import readings

        readings(tmp_path, "paper", "ppo")
