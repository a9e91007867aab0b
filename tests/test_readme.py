"""The README stays short, and every relative link of the README and of docs/*.md resolves."""

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
README_MAX_LINES = 150

_FENCE = re.compile(r"^\s*(```|~~~)")
_CODE_SPAN = re.compile(r"`[^`]*`")
_INLINE_LINK = re.compile(r"!?\[[^\]]*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
_REFERENCE_LINK = re.compile(r"^\s{0,3}\[[^\]]+\]:\s*<?(\S+?)>?(?:\s.*)?$")
_EXTERNAL = re.compile(r"^([a-z][a-z0-9+.-]*:|//|#)", re.IGNORECASE)


def relative_links(text: str) -> list[tuple[int, str]]:
    """Relative link targets of a markdown text as (line number, target without #anchor).

    Inline links and images `[t](x)` / `![t](x)` and reference definitions `[t]: x` count;
    fenced code blocks and `code spans` do not, nor URLs with a scheme and pure #anchors."""
    links, in_fence = [], False
    for number, line in enumerate(text.splitlines(), start=1):
        if _FENCE.match(line):
            in_fence = not in_fence
            continue
        if in_fence:
            continue
        line = _CODE_SPAN.sub("", line)
        targets = _INLINE_LINK.findall(line)
        reference = _REFERENCE_LINK.match(line)
        if reference:
            targets.append(reference.group(1))
        links += [(number, t.split("#")[0]) for t in targets if not _EXTERNAL.match(t)]
    return links


def broken_links(path: Path) -> list[str]:
    """`FILE:LINE: target` for each relative link of `path` that names no existing file."""
    text = path.read_text(encoding="utf-8")
    return [
        f"{path.relative_to(ROOT) if path.is_relative_to(ROOT) else path}:{number}: {target}"
        for number, target in relative_links(text)
        if not (path.parent / target).exists()
    ]


def test_relative_links_finds_links_outside_code_only() -> None:
    text = (
        "See [a](docs/a.md#part), ![fig](results/f.png) and [web](https://x.org).\n"
        "`[not](in/a/span.md)` [anchor](#here)\n"
        "```sh\n[not](in/a/block.md)\n```\n"
        "[ref]: ../b.md\n"
    )
    assert relative_links(text) == [(1, "docs/a.md"), (1, "results/f.png"), (6, "../b.md")]


def test_broken_links_reports_a_missing_target(tmp_path: Path) -> None:
    (tmp_path / "there.md").write_text("x\n", encoding="utf-8")
    page = tmp_path / "page.md"
    page.write_text("[ok](there.md) and\n[gone](missing.md)\n", encoding="utf-8")
    assert broken_links(page) == [f"{page}:2: missing.md"]


def test_readme_is_short() -> None:
    lines = (ROOT / "README.md").read_text(encoding="utf-8").count("\n")
    assert lines <= README_MAX_LINES, f"README.md has {lines} lines (at most {README_MAX_LINES})"


@pytest.mark.parametrize(
    "page",
    [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))],
    ids=lambda page: str(page.relative_to(ROOT)),
)
def test_relative_links_resolve(page: Path) -> None:
    assert broken_links(page) == []
