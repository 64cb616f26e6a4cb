"""Typed results are the contract: a result's key is read in one module, and lambda is spelled
out in one alias table.

The keys a result type writes are collected from its ``to_json`` (the string keys of its dict
literals, of ``out["key"] = ...`` and of ``update``/``dict`` keywords) and from the key tuples
its module declares (``_HEAD``); a key is read where a string literal subscripts something or is
the first argument of ``get``/``pop``. Each written key may be read in one module of
``clm_sim/``, ``controllers/`` and ``experiments/`` only, but for the homonyms listed below: keys
that two file formats spell alike, each read by its own type's module.

A module's reads of keys it writes itself (its own dicts and files: a study's result type
reading its JSON back, a report reading the summary dict it built) are its own; a key read
where it is not written is another module's result, and that is what may happen in one module
only.
"""

from __future__ import annotations

import ast
import re
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("clm_sim", "controllers", "experiments")
SKIP = ()

# The modules that declare result types and write their JSON.
RESULT_MODULES = ("experiments/table.py", "experiments/results.py",
                  "experiments/stats/comparisons.py", "experiments/stats/checks.py",
                  "experiments/records/fit.py", "experiments/report/table_json.py",
                  "controllers/pgnn/fit_record.py")

# Keys two file formats spell alike, and the modules that read each (its own type's reader).
HOMONYMS = {
    # a fit's costs and starts (model file, fits entry) / a row's costs and settings over seeds
    "data_cost": {"controllers/pgnn/fit_record.py", "experiments/table.py"},
    "reg_cost": {"controllers/pgnn/fit_record.py", "experiments/table.py"},
    "starts": {"controllers/pgnn/fit_record.py", "experiments/table.py"},
    # a model file's settings and width / a table row's
    "settings": {"controllers/pgnn/storage.py", "experiments/table.py"},
    "hidden": {"controllers/pgnn/storage.py", "experiments/table.py"},
    # a LIP model file's standard errors / a statistic's spread
    "std": {"controllers/lip.py", "experiments/table.py"},
    # a logged run's meta / a fit's seed
    "seed": {"experiments/testbed.py", "experiments/table.py"},
    # a model file's record / a comparison on measured records
    "record": {"experiments/cli/export_ff.py", "experiments/model_files.py",
               "experiments/stats/comparisons.py"},
    # a fit's iterates (its history, its starts) / the optimizer's state and a model file's
    "cost": {"controllers/pgnn/fit_record.py", "controllers/pgnn/storage.py"},
    "iteration": {"controllers/pgnn/fit_record.py", "controllers/pgnn/training.py"},
    "theta": {"controllers/pgnn/fit_record.py", "controllers/pgnn/storage.py"},
    # an iterate's data term (read by name from a list) / a config's records, a data set
    "data": {"controllers/pgnn/cost.py", "experiments/cli/export_ff.py", "experiments/config.py"},
    # a model file's kind / a table row's
    "kind": {"controllers/lip.py", "experiments/cli/export_ff.py", "experiments/model_files.py",
             "experiments/studies/kinds.py", "experiments/studies/runner.py"},  # a study config's
    # a sweep task's stored rows and their label (the store checks them) / table.json's rows
    "rows": {"experiments/sweeps/run.py", "experiments/sweeps/store.py", "experiments/table.py"},
    "label": {"experiments/sweeps/store.py", "experiments/table.py"},
    # a config's training record (a model file's provenance) / the records' names of a study
    "training": {"experiments/cli/export_ff.py", "experiments/studies/emps/runaway.py"},
    # an iterate's validation cost / the validation record's errors in the runaway study
    "validation": {"controllers/pgnn/fit_record.py", "experiments/studies/emps/runaway.py"},
    # a table row's count of converged fits / a simulation-error stop's flag
    # (experiments.records.output_error), read back by the EMPS benchmark's report
    "converged": {"experiments/table.py", "experiments/studies/emps/benchmark.py"},
}


def _modules():
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            rel = path.relative_to(ROOT).as_posix()
            if not rel.startswith(SKIP):
                yield rel, ast.parse(path.read_text(encoding="utf-8"))


def _string(node) -> str | None:
    return node.value if isinstance(node, ast.Constant) and isinstance(node.value, str) else None


def written_keys(tree: ast.AST) -> set[str]:
    """The keys a module's ``to_json`` functions write and its ``_HEAD`` tuples declare."""
    keys = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Assign) and any(isinstance(t, ast.Name) and t.id.endswith("_HEAD")
                                                for t in node.targets):
            keys |= {_string(e) for e in getattr(node.value, "elts", ())} - {None}
        if not (isinstance(node, ast.FunctionDef) and node.name == "to_json"):
            continue
        for inner in ast.walk(node):
            if isinstance(inner, ast.Dict):
                keys |= {_string(k) for k in inner.keys if k is not None} - {None}
            elif isinstance(inner, ast.Call) and (
                    getattr(inner.func, "attr", None) == "update"
                    or getattr(inner.func, "id", None) == "dict"):
                keys |= {kw.arg for kw in inner.keywords if kw.arg}
            elif isinstance(inner, ast.Subscript) and isinstance(inner.ctx, ast.Store):
                keys |= {_string(inner.slice)} - {None}
    return keys


def own_keys(tree: ast.AST) -> set[str]:
    """Every key a module writes anywhere: dict literals, ``dict(...)``/``update`` keywords and
    ``x["key"] = ...``."""
    keys = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Dict):
            keys |= {_string(k) for k in node.keys if k is not None} - {None}
        elif isinstance(node, ast.Call) and (getattr(node.func, "attr", None) == "update"
                                             or getattr(node.func, "id", None) == "dict"):
            keys |= {kw.arg for kw in node.keywords if kw.arg}
        elif isinstance(node, ast.Subscript) and isinstance(node.ctx, ast.Store):
            keys |= {_string(node.slice)} - {None}
    return keys


def read_keys(tree: ast.AST) -> set[str]:
    """String keys a module reads: ``x["key"]`` and ``x.get("key")``/``x.pop("key")``."""
    keys = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Subscript) and isinstance(node.ctx, ast.Load):
            keys |= {_string(node.slice)} - {None}
        elif (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
              and node.func.attr in ("get", "pop") and node.args):
            keys |= {_string(node.args[0])} - {None}
    return keys


def test_the_result_modules_write_the_keys_the_files_hold():
    """The collector sees the result types' keys (else the next test proves nothing)."""
    trees = dict(_modules())
    keys = set().union(*(written_keys(trees[m]) for m in RESULT_MODULES))
    assert {"mae", "theta_phy_per_seed", "fits", "converged", "kind", "label", "n_seeds",
            "p_holm", "starred", "log_ratio", "force_rms", "checks_passed"} <= keys


def test_no_result_key_is_read_in_two_modules():
    trees = dict(_modules())
    keys = set().union(*(written_keys(trees[m]) for m in RESULT_MODULES))
    readers = defaultdict(set)
    for module, tree in trees.items():
        own = set() if module in RESULT_MODULES else own_keys(tree)
        for key in (read_keys(tree) & keys) - own:
            readers[key].add(module)
    shared = {k: sorted(m) for k, m in readers.items()
              if len(m) > 1 and not m <= HOMONYMS.get(k, set())}
    assert not shared, shared


def test_lambda_is_spelled_out_in_the_alias_table_only():
    """A key-like string that spells lambda (``lambda``, ``continuation_lambda``, ...) appears
    only in the one alias table, ``controllers.pgnn_settings.LAMBDA_KEYS``; everything else
    takes the key from it."""
    spelled = defaultdict(list)
    for module, tree in _modules():
        for node in ast.walk(tree):
            text = _string(node)
            if text and re.fullmatch(r"[a-z_]*lambda[a-z_]*", text):
                spelled[module].append(text)
    assert set(spelled) == {"controllers/pgnn_settings.py"}, dict(spelled)
