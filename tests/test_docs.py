"""The method's pages stay readable: no paragraph of docs/method.md or docs/effects.md is over
300 words (a page of reasons needs each reason findable, not one block of thousands of words)."""

import pathlib
import re

ROOT = pathlib.Path(__file__).resolve().parents[1]
PAGES = ("docs/method.md", "docs/effects.md")
MOST_WORDS = 300
_ITEM = re.compile(r"^\s*([-*+]|\d+\.)\s")


def blocks(text: str) -> list[tuple[str, int, int]]:
    """(kind, first line, words) of each block of a Markdown text: blocks are split on blank
    lines, and inside one a table, a heading and each list item (with its indented continuation
    lines) are blocks of their own; code fences are left out."""
    out: list[tuple[str, int, int]] = []
    kind, first, words, fence = None, 0, 0, False

    def close():
        nonlocal kind, words
        if kind is not None:
            out.append((kind, first, words))
        kind, words = None, 0

    for n, line in enumerate(text.splitlines(), 1):
        if line.strip().startswith("```"):
            close()
            fence = not fence
            continue
        if fence:
            continue
        if not line.strip():
            close()
            continue
        if line.startswith("#"):
            new = "heading"
        elif line.lstrip().startswith("|"):
            new = "table"
        elif _ITEM.match(line):
            new = "list"
        elif kind == "list" and line.startswith((" ", "\t")):
            new = None  # a list item's continuation
        else:
            new = "prose"
        if new is not None and (new != kind or new in ("list", "heading")):
            close()
            kind, first = new, n
        words += len(line.split())
    close()
    return out


def test_blocks_split_as_documented():
    text = "# T\n\none two\nthree\n\n- a b\n  c\n- d\n\n| x | y |\n|---|---|\n\n```\nno\n```\n"
    assert blocks(text) == [
        ("heading", 1, 2),
        ("prose", 3, 3),
        ("list", 6, 4),
        ("list", 8, 2),
        ("table", 10, 6),
    ]


def test_no_paragraph_over_300_words():
    over = [
        f"{page}:{line}: {kind} of {n} words"
        for page in PAGES
        for kind, line, n in blocks((ROOT / page).read_text())
        if n > MOST_WORDS
    ]
    assert not over, "split these blocks (at most 300 words each):\n" + "\n".join(over)
