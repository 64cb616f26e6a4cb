"""The front door and the house behind it: the README stays short and starts with the two set-up
commands, `.ci/run` runs exactly the README's test command, the table the README shows is the
published table's, the pages keep their length and width, and no link into the repository is
broken."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PAGES = [ROOT / "README.md", ROOT / "CHANGELOG.md", *sorted((ROOT / "docs").rglob("*.md"))]
LINK = re.compile(r"\[[^\]]*\]\(([^)#\s]+)(?:#[^)]*)?\)")



def test_readme_is_a_front_door():
    lines = (ROOT / "README.md").read_text(encoding="utf-8").splitlines()
    assert len(lines) <= 150, f"README.md has {len(lines)} lines (at most 150: the rest goes to docs/)"
    first = "\n".join(lines[:25])
    assert "clm-sim run experiments/configs/paper_table.yaml" in first  # the main job
    assert "python -m pytest" in first  # the tests
    assert len(list((ROOT / "docs").rglob("*.md"))) >= 4


def _cells(line: str) -> list[str]:
    return [c.strip() for c in line.strip().strip("|").split("|")]


def test_the_readmes_table_is_the_published_tables():
    """Each row the README shows is a row of docs/results/paper_table.md, cell for cell."""
    def rows(path):  # the first table with an MAE r1 column
        text = (ROOT / path).read_text(encoding="utf-8")
        block = text[text.index("| feedforward | seeds | MAE r1"):].split("\n\n", 1)[0]
        return {_cells(line)[0]: _cells(line) for line in block.splitlines()[2:]}
    shown, published = rows("README.md"), rows("docs/results/paper_table.md")
    excerpt = {k: v for k, v in shown.items() if k in ("feedback only", "LIP") or
               k.startswith("PGNN")}
    assert len(excerpt) == 5, sorted(excerpt)
    for label, cells in excerpt.items():
        assert published.get(label, [])[:len(cells)] == cells, label


def _pages(under: str) -> list[Path]:
    return sorted((ROOT / under).glob("*.md"))


@pytest.mark.parametrize("page", [ROOT / "README.md", *_pages("docs"), *_pages("docs/results")],
                         ids=lambda p: str(p.relative_to(ROOT)))
def test_a_page_keeps_its_length_and_width(page):
    name = str(page.relative_to(ROOT))
    lines = page.read_text(encoding="utf-8").splitlines()
    limit = 150 if name == "README.md" else 250 if "/results/" in name else 400
    assert len(lines) <= limit, f"{name}: {len(lines)} lines (at most {limit})"
    wide = [i for i, line in enumerate(lines, 1) if len(line) > 100 and not line.startswith("|")]
    assert not wide, f"{name}: lines over 100 characters outside tables: {wide}"


def test_ci_runs_the_readmes_test_command():
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    block = re.search(r"```bash\n(.*?)```", readme, re.S).group(1)
    commands = [line for line in block.splitlines() if line and not line.startswith("#")]
    assert len(commands) == 2, commands  # the main job, the tests
    ci = (ROOT / ".ci/run").read_text(encoding="utf-8")
    assert commands[1] in ci.splitlines()


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_no_broken_link(page):
    text = page.read_text(encoding="utf-8")
    broken = [target for target in LINK.findall(text)
              if "://" not in target and not target.startswith("mailto:")
              and not (page.parent / target).exists()]
    assert not broken, f"{page.relative_to(ROOT)} links to missing {broken}"
