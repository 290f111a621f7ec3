"""Every link and file reference in the README, docs/, other Markdown files, config comments, code comments and
docstrings, and the package's strings (messages, report.md) resolves: a linked file exists, a linked section is a
heading there, and a repository path named in the text exists."""
import ast
import io
import re
import tokenize
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
MARKDOWN = sorted(path for pattern in ("*.md", "docs/*.md", "data/README.md", "examples/*.md",
                                       "pcdet_memslidar/assets/*/README.md", "tests/assets/*/README.md",
                                       "tools/*/README.md")
                  for path in REPO.glob(pattern))
TEXT = sorted([*MARKDOWN, *REPO.glob("pcdet_memslidar/**/*.py"), *REPO.glob("tools/**/*.py"),
               *REPO.glob("tests/**/*.py"), *REPO.glob("cfgs/**/*.yaml"), *REPO.glob("examples/*.yaml"),
               REPO / "run.sh", REPO / "pyproject.toml", REPO / "setup.py"])
LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)\)")
# a repository path: one of its top-level folders, then at least one more part (a file or folder name)
PATH = re.compile(r"(?<![\w/.$-])((?:pcdet_memslidar|cfgs|docs|tests|tools|examples)/[\w./-]*\w)")
# paths that are not this repository's: OpenPCDet's (its tools/cfgs/memslidar link to ours), and placeholders
# (an installed package's configs); and the example paths of tests
ELSEWHERE = ("cfgs/memslidar", "cfgs/kitti_models", "tools/cfgs", "tools/train_utils", "tools/scripts",
             "tests/assets/dump.bfpc", "pcdet_memslidar/cfgs")


def elsewhere(reference: str) -> bool:
    return any(reference == other or reference.startswith(other + "/") for other in ELSEWHERE)


def prose(path: Path) -> list[tuple[int, str]]:
    """(line number, text) of what a reader reads in `path`: all of a Markdown, YAML or shell file; in Python, its
    comments and docstrings, and in the package every string (messages, report.md)."""
    text = path.read_text()
    if path.suffix != ".py":
        return list(enumerate(text.splitlines(), 1))
    lines = [(token.start[0], token.string) for token in tokenize.generate_tokens(io.StringIO(text).readline)
             if token.type == tokenize.COMMENT]
    package = path.is_relative_to(REPO / "pcdet_memslidar")
    for node in ast.walk(ast.parse(text)):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and node.body:
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant) and isinstance(
                    first.value.value, str):
                lines += [(first.lineno + offset, line) for offset, line in enumerate(first.value.value.splitlines())]
        if package and isinstance(node, ast.Constant) and isinstance(node.value, str):
            lines.append((node.lineno, node.value))
    return lines


def slug(heading: str) -> str:
    """GitHub's anchor of a Markdown heading."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def anchors(path: Path) -> set[str]:
    return {slug(line.lstrip("#")) for line in path.read_text().splitlines() if line.startswith("#")}


@pytest.mark.parametrize("path", MARKDOWN, ids=lambda path: str(path.relative_to(REPO)))
def test_markdown_links_resolve(path):
    broken = []
    for target in LINK.findall(path.read_text()):
        if re.match(r"[a-z]+:", target):
            continue  # a web address
        file, _, anchor = target.partition("#")
        linked = (path.parent / file).resolve() if file else path
        if not linked.exists():
            broken.append(f"{target}: no such file")
        elif anchor and linked.suffix == ".md" and anchor not in anchors(linked):
            broken.append(f"{target}: no heading with anchor #{anchor}")
    assert broken == []


def test_repository_paths_named_in_text_exist():
    missing = [f"{path.relative_to(REPO)}:{number}: {reference}" for path in TEXT for number, line in prose(path)
               for reference in PATH.findall(line)
               if not elsewhere(reference) and not (REPO / reference.rstrip(".")).exists()]
    assert missing == []
