"""MkDocs hooks: the site is built from the repository as it is, offline.

* ``README.md`` is the site's home page and ``CHANGELOG.md`` its changelog: one text each, read
  on GitHub and on the site alike.
* A link from a page to a file of the repository outside ``docs/`` (a figure under
  ``experiments/results_figures/``, a config) is served from a copy of that file under
  ``repo/`` on the site, so the Markdown keeps the links that work on GitHub and the site shows
  the figures. A link to a file that does not exist is left alone: ``mkdocs build --strict``
  names it and fails.
* A tutorial, ``docs/tutorial/*.py`` in jupytext's percent format, becomes a page (its Markdown
  cells as text, its code cells as code) through jupytext; the script itself is on the site too.
* The Sphinx roles some docstrings use (``:func:`name```) are shown as the code they name.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import jupytext
from mkdocs.structure.files import File

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"
PAGES_FROM_ROOT = {"README.md": "index.md", "CHANGELOG.md": "changelog.md"}
COPIES = "repo"  # where files linked from outside docs/ are served
TUTORIALS = "tutorial"
# A Markdown link or image target: ](target) or ](target#anchor), relative, no scheme.
LINK = re.compile(r"(\]\()([^)\s#]+)((?:#[^)\s]*)?\))")
ROLE = re.compile(r":(?:func|class|meth|mod|data|attr|obj):(?=<code>)")

_sources: dict[str, Path] = {}  # site src_uri -> the file it is read from


def _relative_targets(text: str):
    for match in LINK.finditer(text):
        target = match.group(2)
        if "://" not in target and not target.startswith(("mailto:", "/")):
            yield target


def _site_path(real: Path) -> str | None:
    """Where the repository file ``real`` is on the site (its src_uri), or None if nowhere."""
    rel = real.relative_to(ROOT).as_posix()
    if rel in PAGES_FROM_ROOT:
        return PAGES_FROM_ROOT[rel]
    if real.is_relative_to(DOCS):
        return real.relative_to(DOCS).as_posix()
    if real.is_file():
        return f"{COPIES}/{rel}"
    return None


def on_files(files, config):
    for name, uri in PAGES_FROM_ROOT.items():
        files.append(File.generated(config, uri, abs_src_path=str(ROOT / name)))
        _sources[uri] = ROOT / name
    for script in sorted((DOCS / TUTORIALS).glob("*.py")):
        uri = f"{TUTORIALS}/{script.stem}.md"
        notebook = jupytext.read(script, fmt="py:percent")
        files.append(File.generated(config, uri, content=jupytext.writes(notebook, fmt="md")))
        _sources[uri] = script
    pages = [*(ROOT / n for n in PAGES_FROM_ROOT), *sorted(DOCS.rglob("*.md"))]
    for page in pages:
        for target in _relative_targets(page.read_text(encoding="utf-8")):
            real = (page.parent / target).resolve()
            if (not real.is_relative_to(ROOT) or real.is_relative_to(DOCS) or not real.is_file()
                    or real.relative_to(ROOT).as_posix() in PAGES_FROM_ROOT):
                continue
            uri = f"{COPIES}/{real.relative_to(ROOT).as_posix()}"
            if files.get_file_from_path(uri) is None:
                files.append(File.generated(config, uri, abs_src_path=str(real)))
    return files


def on_page_markdown(markdown, page, config, files):
    """Rewrite each relative link to where its target is on the site."""
    src_uri = page.file.src_uri
    source = _sources.get(src_uri, DOCS / src_uri)
    here = Path(src_uri).parent

    def rewrite(match):
        target = match.group(2)
        if "://" in target or target.startswith(("mailto:", "/")):
            return match.group(0)
        real = (source.parent / target).resolve()
        if not real.is_relative_to(ROOT) or not real.exists():
            return match.group(0)  # strict mode names it
        site = _site_path(real)
        if site is None:
            return match.group(0)
        relative = Path(os.path.relpath(site, here)).as_posix()
        return f"{match.group(1)}{relative}{match.group(3)}"

    return LINK.sub(rewrite, markdown)


def on_page_content(html, page, config, files):
    return ROLE.sub("", html)
