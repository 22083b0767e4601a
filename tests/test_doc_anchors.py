"""Every section a file cites (``docs/manuals.md#2-modbus-rtu``, ``[x](profibus.md#decoder)``, ``[x](#y)``) exists,
and nothing cites the spec digests outside the repository (docs/manuals.md and docs/opcua.md hold what is cited)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
CITATION = re.compile(r"([\w./-]*\.md)#([\w-]+)")
LOCAL_LINK = re.compile(r"\]\(#([\w-]+)\)")
OUTSIDE = re.compile(r"\b(?:MANUALS|DEVICENET|OPCUA|CANOPEN)\.md\b|shared/spec/")
SKIP = {".git", ".venv", "__pycache__", "node_modules"}


def sources() -> list[Path]:
    found = []
    for path in ROOT.rglob("*"):
        parts = path.relative_to(ROOT).parts
        if any(p in SKIP or p.endswith(".egg-info") for p in parts) or path.suffix not in (".md", ".py", ".toml"):
            continue
        if path.is_file():
            found.append(path)
    return sorted(found)


def slug(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped, spaces as hyphens."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def anchors(path: Path) -> set[str]:
    """The anchors of a Markdown file's headings (not of ``#`` lines inside code blocks); repeats get -1, -2."""
    names: set[str] = set()
    counts: dict[str, int] = {}
    fenced = False
    for line in path.read_text(encoding="utf-8").splitlines():
        if line.lstrip().startswith("```"):
            fenced = not fenced
            continue
        heading = re.match(r"#{1,6} (.+)", line)
        if heading and not fenced:
            base = slug(heading.group(1))
            n = counts.get(base, 0)
            counts[base] = n + 1
            names.add(f"{base}-{n}" if n else base)
    return names


def target(cited: str, citing: Path) -> Path | None:
    for base in (citing.parent, ROOT, ROOT / "docs"):
        if (base / cited).is_file():
            return (base / cited).resolve()
    return None


def citations() -> list[tuple[str, Path, str, str]]:
    out = []
    for path in sources():
        text = path.read_text(encoding="utf-8")
        where = str(path.relative_to(ROOT))
        for match in CITATION.finditer(text):
            if "//" not in match.group(1):  # an anchor of another site
                out.append((where, path, match.group(1), match.group(2)))
        if path.suffix == ".md":
            out += [(where, path, path.name, m.group(1)) for m in LOCAL_LINK.finditer(text)]
    return out


def test_every_cited_section_exists() -> None:
    found = citations()
    assert sum(1 for _, _, cited, _ in found if cited.endswith("manuals.md")) >= 20  # the digest is cited
    missing = []
    for where, citing, cited, anchor in found:
        path = target(cited, citing)
        if path is None or anchor not in anchors(path):
            missing.append(f"{where}: {cited}#{anchor}")
    assert not missing, "cited sections that do not exist:\n" + "\n".join(missing)


def test_nothing_cites_the_digest_outside_the_repository() -> None:
    cited = [
        f"{path.relative_to(ROOT)}:{n}"
        for path in sources()
        for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1)
        if OUTSIDE.search(line) and path.name != Path(__file__).name
    ]
    assert not cited, "cite a section of docs/ (manuals.md, opcua.md...) instead: " + ", ".join(cited)


@pytest.mark.parametrize(
    ("heading", "anchor"),
    [("2. Modbus RTU", "2-modbus-rtu"), ("Error answers (decisions)", "error-answers-decisions"),
     ("`starterbus serve`: MQTT", "starterbus-serve-mqtt")],
)  # fmt: skip
def test_slugs_follow_github(heading: str, anchor: str) -> None:
    assert slug(heading) == anchor
