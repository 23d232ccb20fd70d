"""The files that make the project citable and reusable agree with each other: CITATION.cff is
valid YAML naming the paper it reproduces, and the newest release in CHANGELOG.md is the
version pyproject.toml (the one place the version lives) gives the installed package."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

import yaml

import epoet

ROOT = Path(__file__).resolve().parent.parent


def test_citation_names_the_software_and_the_paper():
    cff = yaml.safe_load((ROOT / "CITATION.cff").read_text())
    assert cff["cff-version"] == "1.2.0"
    assert cff["type"] == "software" and cff["license"] == "MIT"
    assert cff["authors"] and cff["message"]
    (paper,) = cff["references"]
    assert paper["title"] == "Open-Ended Learning Strategies for Learning Complex Locomotion Skills"
    assert [a["family-names"] for a in paper["authors"]] == ["Zhou", "Vanschoren"]
    assert paper["year"] == 2021
    assert "arXiv:2206.06796" in [i["value"] for i in paper["identifiers"]]


def test_the_latest_release_in_the_changelog_is_the_package_version():
    version = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]
    releases = re.findall(
        r"^## \[(\d[^\]]*)\] - \d{4}-\d{2}-\d{2}$", (ROOT / "CHANGELOG.md").read_text(), re.M
    )
    assert releases and releases[0] == version
    assert epoet.__version__ == version


def test_the_license_is_the_one_pyproject_names():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert project["license"] == {"text": "MIT"}
    assert (ROOT / "LICENSE").read_text().startswith("MIT License")
