"""The product says what is true now: no working-period words (a numbered session or round, an
issue number, a dated working day, a commit hash in prose, "what moved") in the README, the
docs, the CHANGELOG, the code's comments and strings, the configs' comments or the test names;
the CHANGELOG is by version, and its newest version is ``clm_sim.__version__``."""

from __future__ import annotations

import io
import re
import tokenize
from pathlib import Path

import pytest

import clm_sim

ROOT = Path(__file__).resolve().parent.parent
CODE = ("clm_sim", "controllers", "experiments", "benchmarks", "tests")

ORDINAL = (r"(?:first|second|third|fourth|fifth|sixth|seventh|eighth|ninth|tenth|eleventh|"
           r"twelfth|thirteenth|fourteenth|fifteenth|\d+(?:st|nd|rd|th))")
# A word that names a period of the project's making, in any text a user reads.
HISTORY = re.compile("|".join([
    rf"\b{ORDINAL}[ -](?:working[ -])?(?:session|round|day)\b",
    r"\bround \d+\b",
    r"\bissues? #?\d+\b",
    r"\b2026-1[0-2]-\d\d\b",  # a date of a working day
    r"\bwhat moved\b",
    r"\bearlier run\b",
    r"\bon a slower day\b",
    r"\bsession\b",
]), re.I)
# "session" is also a technical word: a process session, a pytest session fixture, an ONNX
# Runtime session. These uses are what the code means by it, not a working period.
TECHNICAL_SESSION = re.compile(
    r"session(?:[- ](?:fixtures?|scoped?|start|finish)\b|\s*``sid``|\s+sid\b|\.run\b|s\.py)|"
    r"(?:own|new|per|the test|pytest's|whole|same|a|its|for the|once per|that|inherit the|"
    r"pgrp)\s+session\b|[\"']session[\"']|scope=\W?session|session_|_session|InferenceSession|"
    r"session\s*=\s*ort", re.I)
HASH = re.compile(r"(?<![.\d])\b(?=[0-9a-f]*[a-f])(?=[0-9a-f]*\d)[0-9a-f]{7,40}\b")


def _hits(text: str) -> list[str]:
    found = []
    for m in HISTORY.finditer(text):
        if m.group(0).lower() == "session":
            around = text[max(0, m.start() - 20):m.end() + 12]
            if TECHNICAL_SESSION.search(around):
                continue
        found.append(m.group(0))
    return found


def _pages() -> list[Path]:
    return [ROOT / "README.md", ROOT / "CHANGELOG.md", *sorted((ROOT / "docs").rglob("*.md"))]


def _code_files() -> list[Path]:
    files = [p for d in CODE for p in sorted((ROOT / d).rglob("*.py"))]
    return files + sorted((ROOT / "experiments" / "configs").glob("*.yaml"))


def _code_text(path: Path) -> str:
    """What a reader of ``path`` reads as prose: comments and strings of a Python file (with the
    names of its tests), comments of a YAML file."""
    text = path.read_text(encoding="utf-8")
    if path.suffix == ".yaml":
        return "\n".join(line.split("#", 1)[1] for line in text.splitlines() if "#" in line)
    parts = []
    for tok in tokenize.generate_tokens(io.StringIO(text).readline):
        if tok.type in (tokenize.COMMENT, tokenize.STRING):
            parts.append(tok.string)
        elif tok.type == tokenize.NAME and tok.string.startswith("test_"):
            parts.append(tok.string.replace("_", " "))
    return "\n".join(parts)


def _rel(path: Path) -> str:
    return str(path.relative_to(ROOT))


def _check(path: Path, text: str, hashes: bool) -> None:
    if path == Path(__file__).resolve():
        pytest.skip("this file: its examples are the words it catches (test_the_words_are_caught)")
    found = _hits(text) + (HASH.findall(text) if hashes else [])
    assert not found, f"{_rel(path)}: history in the product: {sorted(set(found))}"


# What benchmarks/report.py writes as the provenance of its figures (the date, the commit) is
# the record of a measurement, not history: it is written by the command, never typed.
PROVENANCE = re.compile(r"<!-- provenance:.*?<!-- end provenance -->", re.S)


@pytest.mark.parametrize("page", _pages(), ids=_rel)
def test_a_page_says_what_is_true_now(page):
    _check(page, PROVENANCE.sub("", page.read_text(encoding="utf-8")), hashes=True)


@pytest.mark.parametrize("path", _code_files(), ids=_rel)
def test_code_comments_say_what_is_true_now(path):
    _check(path, _code_text(path), hashes=False)


def test_the_words_are_caught():
    """The patterns catch what they are for and pass the technical uses of "session"."""
    for text in ("in the twelfth session", "round 3 of the review", "issue 24's bar",
                 "measured 2026-11-26", "what moved since", "the 5th day", "this session"):
        assert _hits(text), text
    for text in ("a session-scoped fixture", "in a real process of its own session",
                 "ort.InferenceSession(path)", "session.run([...])", "once per session",
                 "pytest_sessionstart(session)"):
        assert not _hits(text), text
    assert HASH.findall("at commit 7aaf670") and not HASH.findall("a 10 kHz loop, 0.1 µm")


def test_the_changelog_is_by_version_and_its_newest_is_the_packages():
    text = (ROOT / "CHANGELOG.md").read_text(encoding="utf-8")
    versions = re.findall(r"^## (\d+\.\d+\.\d+)\b", text, re.M)
    assert versions, "CHANGELOG.md: no '## x.y.z' version heading"
    assert versions[0] == clm_sim.__version__, (versions[0], clm_sim.__version__)
    numbers = [tuple(map(int, v.split("."))) for v in versions]
    assert numbers == sorted(numbers, reverse=True) and len(set(numbers)) == len(numbers)
