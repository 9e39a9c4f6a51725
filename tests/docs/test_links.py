"""Every relative link, image and anchor in README.md and docs/ resolves (no Blender).

Links are read from the Markdown (``[text](target)``, ``![alt](target)``, and the
``src``/``href`` of HTML tags) outside code blocks and code spans; a target with a
scheme (https:, mailto:) is left alone. Anchors are GitHub's: the heading's text in
lower case, without punctuation, spaces as hyphens, a repeated heading numbered.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"
PAGES = [ROOT / "README.md", *sorted(DOCS.glob("*.md"))]
IMAGES = DOCS / "img"
#: Largest picture in docs/img (they are committed: keep them small).
MAX_IMAGE_KB = 150

_FENCE = re.compile(r"^(```|~~~).*?^\1", re.S | re.M)
_SPAN = re.compile(r"`[^`\n]*`")
_LINK = re.compile(r"!?\[(?:[^\[\]]|\[[^\]]*\])*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
_HTML = re.compile(r"<(?:img|a)\b[^>]*?\b(?:src|href)=\"([^\"]+)\"", re.I)
_HEADING = re.compile(r"^(#{1,6})\s+(.*?)\s*#*\s*$", re.M)


def prose(text: str) -> str:
    """``text`` without fenced code blocks and code spans."""
    return _SPAN.sub("", _FENCE.sub("", text))


def links(text: str) -> list[str]:
    body = prose(text)
    return _LINK.findall(body) + _HTML.findall(body)


def slug(heading: str) -> str:
    """GitHub's anchor of a heading (its Markdown emphasis and code marks dropped)."""
    text = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", heading)  # a link: its text
    text = text.replace("`", "").replace("*", "").strip().lower()
    text = re.sub(r"[^\w\- ]", "", text)
    return text.replace(" ", "-")


def anchors(path: Path) -> set[str]:
    seen: dict[str, int] = {}
    out = set()
    for _, heading in _HEADING.findall(_FENCE.sub("", path.read_text(encoding="utf-8"))):
        s = slug(heading)
        n = seen.get(s, 0)
        seen[s] = n + 1
        out.add(s if n == 0 else f"{s}-{n}")
    return out


def test_the_slug_is_githubs():
    assert slug("Recovery & Plasticity") == "recovery--plasticity"
    assert slug("Keys, drivers and parameter maps") == "keys-drivers-and-parameter-maps"
    assert slug("The demo (`make demo`)") == "the-demo-make-demo"
    assert slug("**Bold** words") == "bold-words"


def test_the_pages_exist():
    names = {p.name for p in PAGES}
    for page in ("README.md", "user-guide.md", "pipeline.md", "api.md", "architecture.md",
                 "benchmarks.md", "testing.md"):
        assert page in names, page


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_every_relative_link_image_and_anchor_resolves(page):
    text = page.read_text(encoding="utf-8")
    bad = []
    for target in links(text):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target, re.I):  # https:, mailto: ...
            continue
        path, _, anchor = target.partition("#")
        dest = (page.parent / path).resolve() if path else page
        if not dest.exists():
            bad.append(f"{target}: no such file {dest.relative_to(ROOT)}")
            continue
        if anchor:
            if dest.suffix != ".md":
                bad.append(f"{target}: an anchor into a file that is not Markdown")
            elif anchor not in anchors(dest):
                bad.append(f"{target}: no heading '#{anchor}' in {dest.relative_to(ROOT)}")
    assert not bad, f"{page.name}:\n" + "\n".join(bad)


def test_every_picture_is_shown_somewhere_and_small():
    used = set()
    for page in PAGES:
        for target in links(page.read_text(encoding="utf-8")):
            used.add((page.parent / target.partition("#")[0]).resolve())
    for img in sorted(IMAGES.iterdir()):
        assert img.resolve() in used, f"docs/img/{img.name} is not shown by any page"
        kb = img.stat().st_size / 1024
        assert kb <= MAX_IMAGE_KB, f"docs/img/{img.name} is {kb:.0f} KB"


def test_no_history_in_the_docs():
    """Today's figures only: the git log keeps the history."""
    for page in PAGES:
        text = page.read_text(encoding="utf-8")
        for pattern in (r"\b(first|second|third|fourth|fifth|sixth|seventh|eighth|ninth"
                        r"|tenth) session\b", r"measured at commit", r"\bhunt ?\d\b",
                        r"\bwas [\d.,]+ ?(ms|s|MB)?, now\b"):
            m = re.search(pattern, text, re.I)
            assert m is None, f"{page.name}: {m.group(0)!r}"
