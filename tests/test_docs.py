"""The docs stay true to the code: the README is a short user guide whose command table names every
subcommand the two CLIs define, its `make` commands are Makefile targets, and no relative link in the
README or docs/ points at a missing file."""

from __future__ import annotations

import argparse
import re
from pathlib import Path

import pytest

from mimickit.cli import build_parser as build_mimickit_parser
from studio.cli import build_parser as build_studio_parser

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
DOCS = sorted((ROOT / "docs").glob("*.md"))
MAX_README_LINES = 200
MAX_README_CELL = 200

FENCE = re.compile(r"^(```|~~~).*?^\1", re.M | re.S)
INLINE_CODE = re.compile(r"`[^`\n]+`")
MD_LINK = re.compile(r"!?\[[^\]\n]*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
HTML_LINK = re.compile(r"<(?:img|a)\b[^>]*?\b(?:src|href)=\"([^\"]+)\"", re.I)
MAKE_CMD = re.compile(r"(?:^|[\s`;&|(])make[ \t]+([A-Za-z0-9_.-]+)")
MAKE_TARGET = re.compile(r"^([A-Za-z0-9_.-]+(?:\s+[A-Za-z0-9_.-]+)*)\s*:(?!=)", re.M)


def subcommands(parser: argparse.ArgumentParser, prefix: str) -> list[str]:
    """Every leaf command of `parser`, as typed: `mimickit motion info`, `mimickit train`, ...
    (argparse has no public way to list subparsers; `_actions` is the one place they are kept)."""
    actions = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if not actions:
        return [prefix]
    names: list[str] = []
    for action in actions:
        for name, sub in action.choices.items():
            names += subcommands(sub, f"{prefix} {name}")
    return names


def table_rows(text: str) -> list[list[str]]:
    """The cells of every Markdown table row outside code blocks (the separator rows left out)."""
    rows = []
    for line in FENCE.sub("", text).splitlines():
        if line.startswith("|") and not re.fullmatch(r"[|\s:-]+", line):
            rows.append([c.strip() for c in line.strip().strip("|").split("|")])
    return rows


def code_text(text: str) -> str:
    """The text inside fenced blocks and inline code spans, one piece a line."""
    blocks = [m.group(0) for m in FENCE.finditer(text)]
    spans = [m.group(0).strip("`") for m in INLINE_CODE.finditer(FENCE.sub("", text))]
    return "\n".join(blocks + spans)


def relative_links(path: Path) -> list[str]:
    """The link targets of a Markdown file that are paths, not URLs or anchors in the same page."""
    prose = INLINE_CODE.sub("", FENCE.sub("", path.read_text()))
    targets = MD_LINK.findall(prose) + HTML_LINK.findall(prose)
    return [t for t in targets if not re.match(r"[a-z][a-z0-9+.-]*:|#", t, re.I)]


def makefile_targets() -> set[str]:
    text = (ROOT / "Makefile").read_text()
    return {name for names in MAKE_TARGET.findall(text) for name in names.split()}


def test_readme_is_a_short_guide() -> None:
    lines = README.read_text().splitlines()
    assert len(lines) <= MAX_README_LINES, f"README.md has {len(lines)} lines, at most {MAX_README_LINES}"
    long_cells = [c[:60] for row in table_rows(README.read_text()) for c in row if len(c) > MAX_README_CELL]
    assert not long_cells, f"README table cells over {MAX_README_CELL} characters: {long_cells}"


@pytest.mark.parametrize(
    ("build", "prog"), [(build_mimickit_parser, "mimickit"), (build_studio_parser, "mimickit-studio")]
)
def test_readme_command_table_names_every_subcommand(build, prog: str) -> None:
    commands = subcommands(build(), prog)
    assert len(commands) > 1, f"{prog}: no subcommands found in its parser"
    first_cells = {row[0] for row in table_rows(README.read_text())}
    missing = [c for c in commands if f"`{c}`" not in first_cells]
    assert not missing, f"README.md's command table lacks {missing}"


def test_subcommands_walks_nested_parsers() -> None:
    parser = argparse.ArgumentParser(prog="tool")
    sub = parser.add_subparsers()
    sub.add_parser("plain")
    nested = sub.add_parser("group").add_subparsers()
    nested.add_parser("one")
    nested.add_parser("two")
    assert subcommands(parser, "tool") == ["tool plain", "tool group one", "tool group two"]


@pytest.mark.parametrize("path", [README, *DOCS], ids=lambda p: p.name)
def test_relative_links_point_to_files(path: Path) -> None:
    missing = [t for t in relative_links(path) if not (path.parent / t.split("#")[0]).exists()]
    assert not missing, f"{path.relative_to(ROOT)} links to missing files: {missing}"


def test_relative_links_finds_links_and_skips_urls_and_code(tmp_path: Path) -> None:
    page = tmp_path / "page.md"
    page.write_text(
        '[a](a.md) ![b](img/b.png) [c](https://x.org/c.md) [d](#d) <img src="e.png" width="5">\n'
        "`[f](f.md)`\n```\n[g](g.md)\n```\n[h](h.md#part)\n"
    )
    assert relative_links(page) == ["a.md", "img/b.png", "h.md#part", "e.png"]


def test_readme_make_commands_are_makefile_targets() -> None:
    named = set(MAKE_CMD.findall(code_text(README.read_text())))
    assert {"studio", "test"} <= named, f"README.md should name `make studio` and `make test`, names {named}"
    unknown = named - makefile_targets()
    assert not unknown, f"README.md names make targets the Makefile lacks: {sorted(unknown)}"


@pytest.mark.parametrize("path", DOCS, ids=lambda p: p.name)
def test_docs_make_commands_are_makefile_targets(path: Path) -> None:
    unknown = set(MAKE_CMD.findall(code_text(path.read_text()))) - makefile_targets()
    assert not unknown, f"{path.relative_to(ROOT)} names make targets the Makefile lacks: {sorted(unknown)}"


def test_makefile_targets_are_rules_not_variables() -> None:
    targets = makefile_targets()
    assert {"setup", "studio", "test", "test-unit", "test-newton"} <= targets
    assert not {"VENV", "NEWTON_VENV", "PY", "BIN"} & targets
    assert MAKE_CMD.findall("make studio   # x\n`make` (into `.venv`)\ncd a && make test-unit") == [
        "studio",
        "test-unit",
    ]
