"""The documentation the code and the docs point at exists (issue 14)."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SOURCES = [p for top in ("tmcl_server", "interpreter", "axes", "tmcl_spec", "scripts", "tests", "docs")
           for p in (ROOT / top).rglob("*") if p.suffix in (".py", ".md", ".toml", ".sh")]
SOURCES = [p for p in SOURCES if p != Path(__file__).resolve()]  # its own examples are not links
SOURCES += [ROOT / "README.md", ROOT / "pyproject.toml"]
#: ``docs/name.md`` (or .toml) anywhere in a comment, docstring or text.
DOC_REFERENCE = re.compile(r"(?<![\w/])docs/[\w./-]*\w")
#: Markdown links to local files: ``[text](path)``.
MARKDOWN_LINK = re.compile(r"\]\(([^)#:\s]+)(?:#[^)]*)?\)")


def test_every_cited_doc_exists():
    missing = []
    for path in SOURCES:
        for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            for reference in DOC_REFERENCE.findall(line):
                if not (ROOT / reference).exists():
                    missing.append(f"{path.relative_to(ROOT)}:{number}: {reference}")
    assert not missing, "\n".join(missing)


def test_markdown_links_point_at_files_that_exist():
    broken = []
    for path in [ROOT / "README.md", *(ROOT / "docs").glob("*.md")]:
        for target in MARKDOWN_LINK.findall(path.read_text(encoding="utf-8")):
            if not (path.parent / target).exists():
                broken.append(f"{path.relative_to(ROOT)}: {target}")
    assert not broken, "\n".join(broken)


def test_readme_points_at_the_compatibility_section():
    assert "docs/compatibility.md" in (ROOT / "README.md").read_text(encoding="utf-8")
