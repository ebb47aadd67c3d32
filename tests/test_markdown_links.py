"""The Markdown reads as it lies in the repository (on GitHub, in an editor), not only on the built
site: every relative link names a file that exists, every anchor a heading of that file, and the
reference pages kept in docs/reference/ are what docs/gen_reference.py writes from the code now."""
from __future__ import annotations

import importlib.util
import re
import unicodedata
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SKIP_DIRS = {".git", "out", "site", "node_modules", ".venv", "venv", "build", "dist"}
LINK = re.compile(r"!?\[(?:[^\[\]]|\[[^\]]*\])*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
FENCE = re.compile(r"^\s*(```|~~~)")


def _markdown_files() -> list[Path]:
    return sorted(p for p in ROOT.rglob("*.md")
                  if not SKIP_DIRS.intersection(p.relative_to(ROOT).parts[:-1])
                  and not any(part.endswith(".egg-info") for part in p.parts))


def _prose(text: str, inline_code: bool = False) -> str:
    """The text outside fenced code blocks, and outside inline code unless ``inline_code`` (a link
    shown as code is not a link; a heading's code is part of its anchor)."""
    out, fenced = [], False
    for line in text.splitlines():
        if FENCE.match(line):
            fenced = not fenced
            continue
        if not fenced:
            out.append(line.replace("`", "") if inline_code else re.sub(r"`[^`]*`", "", line))
    return "\n".join(out)


def github_slug(heading: str) -> str:
    """The anchor GitHub gives a heading: lower case, punctuation dropped, spaces to hyphens."""
    text = re.sub(r"<[^>]+>", "", heading).strip().lower()
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", text)         # a link's text
    kept = "".join(c for c in text if c in " -_" or unicodedata.category(c)[0] in "LN")
    return kept.replace(" ", "-")


def _anchors(path: Path) -> set[str]:
    anchors, seen = set(), {}
    for line in _prose(path.read_text(encoding="utf-8"), inline_code=True).splitlines():
        m = re.match(r"^#{1,6}\s+(.*?)\s*#*\s*$", line)
        if not m:
            continue
        slug = github_slug(m.group(1))
        n = seen.get(slug, 0)
        seen[slug] = n + 1
        anchors.add(slug if n == 0 else f"{slug}-{n}")
    anchors.update(re.findall(r"<a\s+(?:name|id)=\"([^\"]+)\"", path.read_text(encoding="utf-8")))
    return anchors


def broken_links(path: Path) -> list[str]:
    problems = []
    for target in LINK.findall(_prose(path.read_text(encoding="utf-8"))):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target, re.I) or target.startswith("{"):
            continue                                   # http:, mailto:, a template's placeholder
        file_part, _, anchor = target.partition("#")
        dest = path if not file_part else (path.parent / file_part).resolve()
        if not dest.exists():
            problems.append(f"{target}: no such file")
        elif anchor and dest.suffix == ".md" and anchor not in _anchors(dest):
            problems.append(f"{target}: no heading with the anchor #{anchor}")
    return problems


def test_every_relative_link_in_the_markdown_resolves():
    files = _markdown_files()
    assert len(files) > 20
    problems = [f"{p.relative_to(ROOT)}: {msg}" for p in files for msg in broken_links(p)]
    assert not problems, "\n".join(problems)


def test_the_link_checker_finds_a_broken_file_and_anchor(tmp_path):
    (tmp_path / "a.md").write_text("# Title here\n\n## The `[canopen]` section, and more\n", encoding="utf-8")
    page = tmp_path / "b.md"
    page.write_text("[ok](a.md) [ok](a.md#title-here) [ok](a.md#the-canopen-section-and-more)\n"
                    "[bad](missing.md) [bad](a.md#nowhere)\n```\n[in code](nowhere.md)\n```\n", encoding="utf-8")
    assert broken_links(page) == ["missing.md: no such file", "a.md#nowhere: no heading with the anchor #nowhere"]


def _gen():
    spec = importlib.util.spec_from_file_location("gen_reference", ROOT / "docs" / "gen_reference.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.parametrize("uri", ["reference/config.md", "reference/effects.md", "reference/commands.md",
                                 "reference/json.md"])
def test_the_kept_reference_pages_are_what_the_code_generates(uri):
    gen = _gen()
    kept = (ROOT / "docs" / uri).read_text(encoding="utf-8")
    assert kept == gen.PAGES[uri](), (f"docs/{uri} is stale: run python docs/gen_reference.py docs "
                                      "and commit the pages it writes")
