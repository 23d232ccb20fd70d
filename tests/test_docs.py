"""The README stays short, the documentation site's nav names only pages that exist, and no page
links to a file the site leaves out (the strict build in `make test`, `make docs`, checks every
other link and anchor)."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import yaml

ROOT = Path(__file__).resolve().parent.parent
README_MAX_LINES = 250


def nav_pages(entries: Any) -> list[str]:
    """Every page path in a mkdocs nav (a list of pages, `title: page` and `title: [section]`)."""
    if isinstance(entries, str):
        return [entries]
    if isinstance(entries, list):
        return [page for entry in entries for page in nav_pages(entry)]
    if isinstance(entries, dict):
        return [page for value in entries.values() for page in nav_pages(value)]
    raise AssertionError(f"unexpected nav entry {entries!r}")


def test_the_readme_has_at_most_250_lines() -> None:
    lines = (ROOT / "README.md").read_text(encoding="utf-8").splitlines()
    assert len(lines) <= README_MAX_LINES, f"README.md has {len(lines)} lines"


def test_every_page_in_the_nav_exists() -> None:
    config = yaml.safe_load((ROOT / "mkdocs.yml").read_text(encoding="utf-8"))
    docs = ROOT / config.get("docs_dir", "docs")
    pages = nav_pages(config["nav"])
    assert pages, "mkdocs.yml has no nav"
    missing = [page for page in pages if not (docs / page).is_file()]
    assert not missing, f"pages in mkdocs.yml's nav that do not exist under {docs}: {missing}"
    assert len(pages) == len(set(pages)), "a page is listed twice in the nav"


def test_every_page_under_docs_is_in_the_nav() -> None:
    """A page left out of the nav is unreachable from the site's menu; the records under
    docs/results/ and the figures' tables under docs/figures/ are data, excluded from the
    build (mkdocs.yml exclude_docs), except the records' README."""
    config = yaml.safe_load((ROOT / "mkdocs.yml").read_text(encoding="utf-8"))
    docs = ROOT / config.get("docs_dir", "docs")
    pages = set(nav_pages(config["nav"]))
    on_disk = {
        path.relative_to(docs).as_posix()
        for path in docs.rglob("*.md")
        if not path.relative_to(docs).as_posix().startswith(("results/", "figures/"))
    }
    assert on_disk <= pages, f"pages not in mkdocs.yml's nav: {sorted(on_disk - pages)}"
    assert "results/README.md" in pages


def test_no_page_links_to_a_file_the_site_excludes(tmp_path, caplog) -> None:
    """A link to a file of mkdocs.yml's exclude_docs is a 404 in the built site, which mkdocs
    only logs at INFO, so the strict build passes it: the build's own log catches it here."""
    from mkdocs.commands.build import build
    from mkdocs.config import load_config

    caplog.set_level(logging.INFO)
    build(load_config(str(ROOT / "mkdocs.yml"), site_dir=str(tmp_path / "site")))
    excluded = [
        r.getMessage() for r in caplog.records if "excluded from the built" in r.getMessage()
    ]
    assert not excluded, excluded
    assert (tmp_path / "site" / "results" / "compute-final-choice" / "index.html").is_file()
