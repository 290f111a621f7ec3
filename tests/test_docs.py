"""The docs state what the code does: no commit hash or run narration in prose (only the generated tables' headers
name commits), README short enough for a newcomer's first minutes, docs/ short enough to read."""
import re
from pathlib import Path

from pcdet_memslidar.experiments.publish import strip_blocks

REPO = Path(__file__).resolve().parents[1]
PAGES = [REPO / "README.md", REPO / "CHANGELOG.md", *sorted((REPO / "docs").glob("*.md"))]
COMMIT = re.compile(r"\b(?=[0-9a-f]*[0-9])(?=[0-9a-f]*[a-f])[0-9a-f]{7,40}\b")  # a hex word with digits and letters


def test_no_page_cites_a_commit_outside_its_generated_blocks():
    cited = [f"{page.relative_to(REPO)}: {word}" for page in PAGES
             for word in COMMIT.findall(strip_blocks(page.read_text()))]
    assert cited == []


def test_the_commit_pattern_finds_short_and_long_hashes_but_not_words_or_numbers():
    assert COMMIT.findall("at 5921c34, e13ee5b0c1d2 and 2026112; a decade, added") == ["5921c34", "e13ee5b0c1d2"]


def test_readme_and_docs_stay_short():
    assert len((REPO / "README.md").read_text().splitlines()) < 150
    assert sum(len(page.read_text().splitlines()) for page in (REPO / "docs").glob("*.md")) < 1500
