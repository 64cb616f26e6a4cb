"""The API reference: every public name (``clm_sim.__all__``) is on the reference page, its
docstring has the numpydoc sections, and every example in it runs and prints what it shows."""

from __future__ import annotations

import ast
import doctest
import importlib
import inspect
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

import clm_sim

ROOT = Path(__file__).resolve().parent.parent
REFERENCE = ROOT / "docs" / "reference.md"
NAMES = list(clm_sim.__all__)


def where(name: str) -> str:
    """The module that defines the public ``name`` (where mkdocstrings finds it)."""
    if name == "__version__":
        return "clm_sim"
    obj = getattr(clm_sim, name)
    if inspect.isclass(obj) or inspect.isfunction(obj):
        return obj.__module__
    return clm_sim._EXPORTS[name]


def docstring(name: str) -> str:
    """The docstring the reference renders: the object's own, or for a module attribute (a
    dict, a string) the string literal that follows its assignment."""
    module = importlib.import_module(where(name))
    obj = getattr(module, name)
    if inspect.isclass(obj) or inspect.isfunction(obj):
        return inspect.getdoc(obj) or ""
    body = ast.parse(Path(module.__file__).read_text(encoding="utf-8")).body
    for node, after in zip(body, body[1:]):
        targets = (node.targets if isinstance(node, ast.Assign) else
                   [node.target] if isinstance(node, ast.AnnAssign) else [])
        if any(isinstance(t, ast.Name) and t.id == name for t in targets):
            if isinstance(after, ast.Expr) and isinstance(after.value, ast.Constant):
                return inspect.cleandoc(after.value.value)
    return ""


def sections(text: str) -> set[str]:
    return set(re.findall(r"^(\w[\w ]*)\n-{3,}$", text, re.M))


def test_reference_page_lists_every_public_name():
    entries = re.findall(r"^::: ([\w.]+)$", REFERENCE.read_text(encoding="utf-8"), re.M)
    listed = {path.rsplit(".", 1)[1]: path for path in entries}
    assert len(entries) == len(listed), "a name is listed twice"
    assert sorted(listed) == sorted(NAMES)
    for name, path in listed.items():  # the defining module: what mkdocstrings reads
        assert path == f"{where(name)}.{name}"


@pytest.mark.parametrize("name", NAMES)
def test_docstring_has_numpydoc_sections(name):
    obj = getattr(clm_sim, name)
    text = docstring(name)
    needed = {"Examples"}
    if inspect.isfunction(obj):
        needed |= {"Parameters", "Returns", "Raises"}
    elif inspect.isclass(obj) and not issubclass(obj, Exception):
        needed |= {"Parameters", "Raises"}
    assert needed <= sections(text), f"{name}: missing {sorted(needed - sections(text))}"
    if "Parameters" in needed:  # every parameter of the signature is documented
        params = inspect.signature(obj).parameters
        entries = re.findall(r"^\**(\w+(?:, \**\w+)*)(?: :.*)?$", text, re.M)
        documented = {p.strip("*") for entry in entries for p in entry.split(", ")}
        missing = [p for p in params if p not in documented]
        assert not missing, f"{name}: parameters not documented: {missing}"


@pytest.mark.parametrize("name", NAMES)
def test_docstring_examples_run(name, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # an example that writes a file writes it here
    test = doctest.DocTestParser().get_doctest(docstring(name), {}, name, None, 0)
    assert test.examples, f"{name}: no example"
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS)
    runner.run(test)
    assert runner.failures == 0, f"{name}: {runner.failures} of {runner.tries} examples failed"


@pytest.mark.slow  # .ci/run builds the site too; this names what it must hold
def test_built_site_shows_every_public_name(tmp_path):
    """The reference page as built: one rendered entry per public name (mkdocstrings names
    an entry's heading by its full path); the tutorial is a page; every image a page shows is
    on the site."""
    pytest.importorskip("mkdocstrings_handlers.python")
    site = tmp_path / "site"
    subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-d", str(site)],
                   cwd=ROOT, check=True, env={**os.environ, "NO_MKDOCS_2_WARNING": "1"})
    html = (site / "reference" / "index.html").read_text(encoding="utf-8")
    missing = [name for name in NAMES if f'id="{where(name)}.{name}"' not in html]
    assert not missing, f"not rendered: {missing}"
    tutorial = site / "tutorial" / "record_to_feedforward" / "index.html"
    assert "From a measured record to a feedforward on the machine" in tutorial.read_text(
        encoding="utf-8")
    pages = list(site.rglob("*.html"))
    images = [(page, src) for page in pages
              for src in re.findall(r'<img [^>]*src="([^"]+)"', page.read_text(encoding="utf-8"))
              if "://" not in src]
    assert len(images) >= 5  # the results pages' figures
    missing = [src for page, src in images if not (page.parent / src).resolve().is_file()]
    assert not missing, f"images not on the site: {missing}"


def test_ci_builds_the_site_strictly():
    """CI builds the site with --strict and without --quiet (which hides the warnings that
    --strict turns into a failure), with the docs extra installed."""
    run = (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    build = [line for line in run.splitlines() if "mkdocs build" in line and
             not line.lstrip().startswith("#")]
    assert len(build) == 1 and "--strict" in build[0]
    assert not re.search(r"\s(-q|--quiet)\b", build[0])
    assert '".[dev,export,docs]"' in (ROOT / ".ci" / "install").read_text(encoding="utf-8")


def test_every_docstring_example_in_the_product_is_one_of_these():
    """An example is run by the tests or not there: every ``>>>`` line of clm_sim, controllers
    and experiments is in a public name's docstring, which the test above runs."""
    prompt = re.compile(r"^\s*>>> ", re.M)
    in_code = sum(len(prompt.findall(path.read_text(encoding="utf-8")))
                  for package in ("clm_sim", "controllers", "experiments")
                  for path in (ROOT / package).rglob("*.py"))
    run = sum(len(prompt.findall(docstring(name))) for name in NAMES)
    assert in_code == run
