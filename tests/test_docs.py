"""The README and docs/: short enough to read, every docs file reachable, every link resolving."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
README = ROOT / "README.md"
PAGES = [README, *sorted(DOCS.glob("*.md"))]
LINK = re.compile(r"\]\(([^)\s]+)\)")


def links(page: Path) -> list[str]:
    """Relative link targets of a markdown page (web addresses left out)."""
    return [t for t in LINK.findall(page.read_text()) if not re.match(r"[a-z]+://|mailto:", t)]


def anchor(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped, spaces to hyphens."""
    text = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return text.replace(" ", "-")


def anchors(page: Path) -> set[str]:
    text = re.sub(r"```.*?```", "", page.read_text(), flags=re.S)
    return {anchor(m) for m in re.findall(r"^#+ (.+)$", text, flags=re.M)}


def test_readme_is_a_short_guide() -> None:
    assert len(README.read_text().splitlines()) <= 250


def test_every_docs_file_is_linked_from_the_readme_or_a_docs_page() -> None:
    linked = {
        (page.parent / target.split("#")[0]).resolve()
        for page in PAGES
        for target in links(page)
        if target.split("#")[0]
    }
    orphans = [p.name for p in sorted(DOCS.rglob("*")) if p.is_file() and p.resolve() not in linked]
    assert not orphans, f"not linked from README.md or a docs page: {orphans}"


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_every_relative_link_resolves(page: Path) -> None:
    broken = []
    for target in links(page):
        path, _, fragment = target.partition("#")
        dest = (page.parent / path).resolve() if path else page
        missing_anchor = fragment and dest.suffix == ".md" and fragment not in anchors(dest)
        if not dest.exists() or missing_anchor:
            broken.append(target)
    assert not broken, f"{page.name}: broken links {broken}"


def test_anchor_follows_githubs_rule() -> None:
    assert anchor("Several clients at once: one process per core") == (
        "several-clients-at-once-one-process-per-core"
    )
    assert anchor("`POST /v1/estimate`, JSON body") == "post-v1estimate-json-body"
