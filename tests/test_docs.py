"""The README, docs/, results/, the changelog and the shipped configs cite only files that are in
the repository."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = [
    ROOT / "README.md",
    ROOT / "CHANGELOG.md",
    *sorted((ROOT / "docs").glob("*.md")),
    *sorted((ROOT / "results").glob("**/*.md")),
    *sorted((ROOT / "configs").glob("*.yaml")),
]
#: A repository path as the docs write it: a top-level folder, then path characters.
_TOP = "rodctl|docs|benchmarks|tests|configs|results|examples"
_PATH = re.compile(rf"(?<![\w/.-])((?:{_TOP})/[\w./*{{}},-]*[\w*}}])")


def _expand(path: str) -> list[str]:
    """`a/{b,c}.py` -> [`a/b.py`, `a/c.py`] (the README's brace shorthand)."""
    m = re.search(r"\{([^{}]*)\}", path)
    if not m:
        return [path]
    return [
        q
        for alt in m.group(1).split(",")
        for q in _expand(path[: m.start()] + alt + path[m.end() :])
    ]


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_cited_paths_exist(doc):
    text = doc.read_text(encoding="utf-8")
    missing = []
    for raw in _PATH.findall(text):
        if re.fullmatch(r"rodctl/ShapeServo(RL|Goal)?-v\d+", raw):
            continue  # the Gymnasium environment id, not a path
        for path in _expand(raw.rstrip(".,")):
            if not list(ROOT.glob(path)):
                missing.append(path)
    assert not missing, f"{doc.name} cites paths not in the repository: {missing}"


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_no_citation_of_material_outside_the_repository(doc):
    text = doc.read_text(encoding="utf-8")
    for outside in ("shared/", "method-notes", "research/", "architecture.md"):
        assert outside not in text, f"{doc.name} cites {outside}"
