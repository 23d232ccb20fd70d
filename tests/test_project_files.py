"""The files that make the project citable and reusable agree with each other: CITATION.cff is
valid CFF 1.2 YAML carrying the software's version and release date and the paper it reproduces
as its preferred citation, which the README and the site's home cite; the newest release in
CHANGELOG.md is the version pyproject.toml (the one place the version lives) gives the
installed package."""

from __future__ import annotations

import re
import subprocess
import sys
import tomllib
from pathlib import Path

import yaml

import epoet

ROOT = Path(__file__).resolve().parent.parent
PAPER = "Open-Ended Learning Strategies for Learning Complex Locomotion Skills"


def latest_release() -> tuple[str, str]:
    """The newest release heading of CHANGELOG.md: (version, date)."""
    releases = re.findall(
        r"^## \[(\d[^\]]*)\] - (\d{4}-\d{2}-\d{2})$", (ROOT / "CHANGELOG.md").read_text(), re.M
    )
    assert releases, "CHANGELOG.md has no release heading"
    return releases[0]


def test_citation_carries_the_release_and_prefers_the_paper():
    cff = yaml.safe_load((ROOT / "CITATION.cff").read_text())
    assert cff["cff-version"] == "1.2.0"
    assert cff["type"] == "software" and cff["license"] == "MIT"
    assert cff["authors"] and cff["message"] and cff["title"]
    assert (cff["version"], cff["date-released"]) == latest_release()  # a quoted date: a string
    assert cff["version"] == epoet.__version__
    paper = cff["preferred-citation"]
    assert paper["type"] == "article" and paper["title"] == PAPER
    assert [a["family-names"] for a in paper["authors"]] == ["Zhou", "Vanschoren"]
    assert paper["year"] == 2022 and paper["url"] == "https://arxiv.org/abs/2206.06796"
    assert "arXiv:2206.06796" in [i["value"] for i in paper["identifiers"]]
    # the year is the one its identifier carries (arXiv YYMM.NNNNN)
    assert paper["year"] == 2000 + int(paper["url"].rsplit("/", 1)[1][:2])


def test_the_readme_and_the_sites_home_cite_the_paper():
    paper = yaml.safe_load((ROOT / "CITATION.cff").read_text())["preferred-citation"]
    authors = " and ".join(f"{a['given-names']} {a['family-names']}" for a in paper["authors"])
    reference = f"{authors}. *{paper['title']}*. {paper['year']}."
    for page in (ROOT / "README.md", ROOT / "docs" / "index.md"):
        text = " ".join(re.sub(r"^> ?", "", page.read_text(), flags=re.M).split())  # quoted
        assert reference in text, page.name
        assert f"[arXiv:2206.06796]({paper['url']})" in text, page.name


def test_version_prints_the_package_version():
    done = subprocess.run(
        [sys.executable, "-m", "epoet", "--version"], cwd=ROOT, capture_output=True, text=True
    )
    assert done.returncode == 0 and done.stdout == f"epoet {epoet.__version__}\n"


def test_the_latest_release_in_the_changelog_is_the_package_version():
    version = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]
    assert latest_release()[0] == version
    assert epoet.__version__ == version


def test_the_license_is_the_one_pyproject_names():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert project["license"] == {"text": "MIT"}
    assert (ROOT / "LICENSE").read_text().startswith("MIT License")
