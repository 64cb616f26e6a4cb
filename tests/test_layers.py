"""The import graph points down and has no cycle, and ``experiments/`` is sorted by kind.

Layers, bottom to top: ``clm_sim`` (physics, data) -> ``controllers`` (feedback, feedforwards,
their identification) -> ``experiments`` -> the commands (the ``experiments.cli`` package).
Inside ``experiments`` the library (the pipeline at its root: config, testbed, results, table,
plots, the model-file reader; ``stats``, ``records``, ``processes``, ``report`` and
``diagnosis``) is below the runner, and the runner below the studies (``experiments.studies``)
and sweeps (``experiments.sweeps``) built on it. The package facade ``clm_sim/__init__.py`` is
the public API: it resolves its names lazily (PEP 562) and is the only place allowed to name a
higher layer. Every import counts, function-local ones too: a local import that hides a cycle is
still a cycle.
"""

from __future__ import annotations

import ast
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("clm_sim", "controllers", "experiments")
TOP = ("experiments.cli", 3)  # the commands: this package and its modules


def _modules() -> dict[str, Path]:
    out = {}
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            parts = path.relative_to(ROOT).with_suffix("").parts
            name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
            out[name] = path
    return out


MODULES = _modules()


def _within(module: str, package: str) -> bool:
    return module == package or module.startswith(package + ".")


def layer(module: str) -> int:
    if _within(module, TOP[0]):
        return TOP[1]
    return PACKAGES.index(module.split(".")[0])


def _resolve(name: str) -> str | None:
    """The project module an imported name refers to (``a.b.c`` -> ``a.b`` if ``c`` is a name)."""
    while name:
        if name in MODULES:
            return name
        name = name.rpartition(".")[0]
    return None


def imports(module: str) -> set[str]:
    """Project modules imported anywhere in ``module`` (module level or inside functions)."""
    tree = ast.parse(MODULES[module].read_text(encoding="utf-8"))
    is_package = MODULES[module].name == "__init__.py"
    found = set()
    for node in ast.walk(tree):
        names = []
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = module.split(".") if is_package else module.split(".")[:-1]
                anchor = anchor[:len(anchor) - node.level + 1]
                base = ".".join(anchor + ([base] if base else []))
            names = [f"{base}.{a.name}" for a in node.names] + [base]
        for name in names:
            target = _resolve(name)
            if target and target != module:
                found.add(target)
    return found


GRAPH = {m: imports(m) for m in MODULES}
# The study runner finds the study kinds by walking the packages of experiments/studies/
# (pkgutil) for their ``kind`` module, an import by name that ast cannot see: each is an edge.
STUDY_PACKAGES = sorted(m for m, path in MODULES.items()
                        if m.startswith("experiments.studies.") and m.count(".") == 2
                        and path.name == "__init__.py")
GRAPH["experiments.studies.runner"] |= {f"{p}.kind" for p in STUDY_PACKAGES
                                        if f"{p}.kind" in MODULES}


def test_the_layers_are_the_expected_packages():
    assert {"clm_sim.plant", "controllers.pid", "experiments.testbed",
            "experiments.cli"} <= set(MODULES)


@pytest.mark.parametrize("module", sorted(m for m in MODULES if m != "clm_sim"))
def test_no_module_imports_a_layer_above_it(module):
    upward = sorted(t for t in GRAPH[module] if layer(t) > layer(module))
    assert not upward, f"{module} (layer {layer(module)}) imports {upward}"


EXPERIMENT_TIERS = (("experiments.studies", "experiments.sweeps"), ("experiments.runner",))


def _tier(module: str) -> int:
    """0: the experiments library; 1: the runner; 2: studies and sweeps."""
    for level, prefixes in ((2, EXPERIMENT_TIERS[0]), (1, EXPERIMENT_TIERS[1])):
        if any(_within(module, p) for p in prefixes):
            return level
    return 0


@pytest.mark.parametrize("module", sorted(m for m in MODULES if m.startswith("experiments.")
                                          and not _within(m, TOP[0])))
def test_the_experiments_library_does_not_import_the_studies_sweeps_or_runner(module):
    upward = sorted(t for t in GRAPH[module] if t.startswith("experiments.")
                    and not _within(t, TOP[0]) and _tier(t) > _tier(module))
    assert not upward, f"{module} imports {upward}, which are built on it"


def test_import_graph_has_no_cycle():
    state, stack, cycles = {}, [], []

    def visit(m):
        state[m] = "open"
        stack.append(m)
        for t in sorted(GRAPH[m]):
            if state.get(t) == "open":
                cycles.append(stack[stack.index(t):] + [t])
            elif t not in state:
                visit(t)
        stack.pop()
        state[m] = "done"

    for m in sorted(GRAPH):
        if m not in state:
            visit(m)
    assert not cycles, "import cycles: " + "; ".join(" -> ".join(c) for c in cycles)


def test_the_process_lifecycle_is_a_module_the_graph_sees():
    """The signal and exit handling stops the workers and removes temporary folders: it names
    those modules in imports (an edge of this graph), never reaches them through sys.modules,
    and the command line only dispatches to it."""
    assert ({"experiments.processes.workers", "clm_sim.outdir"}
            <= GRAPH["experiments.processes.process"])
    assert "experiments.processes.process" in GRAPH["experiments.cli"]
    hidden = re.compile(r"sys\.modules(\.get\(|\[)\s*['\"](clm_sim|controllers|experiments)")
    reached = [m for m, path in MODULES.items() if hidden.search(path.read_text("utf-8"))]
    assert not reached, f"{reached} reach project modules through sys.modules"


def test_the_experiments_root_holds_the_pipeline_only():
    """At most eight modules (``__init__.py`` included) at the root of ``experiments/``: the
    commands, the statistics, the records, the process plumbing and each study live in packages
    named for what they hold."""
    root = sorted(p.name for p in (ROOT / "experiments").glob("*.py"))
    assert len(root) <= 8, root


@pytest.mark.parametrize("package", STUDY_PACKAGES)
def test_every_study_package_declares_its_study(package):
    """A study kind is its package: ``KIND``, ``SECTION`` and ``study()`` in its ``kind.py``,
    whose ``study()`` imports the module that declares the study (an edge of the graph), and
    the runner finds it."""
    import importlib

    from experiments.studies.protocol import Study
    from experiments.studies.runner import declared

    kind = importlib.import_module(f"{package}.kind")
    study = kind.study()
    assert isinstance(study, Study)
    assert (study.kind, study.section) == (kind.KIND, kind.SECTION)
    assert declared()[kind.KIND] == (kind.SECTION, kind)
    assert f"{package}.kind" in GRAPH["experiments.studies.runner"]
    assert any(_within(t, package) for t in GRAPH[f"{package}.kind"]), package


def test_the_study_kinds_are_the_packages_the_runner_finds():
    from experiments.studies.runner import declared

    assert sorted(k.__name__ for _, k in declared().values()) == [
        f"{p}.kind" for p in STUDY_PACKAGES]
    assert len({section for section, _ in declared().values()}) == len(declared())


def test_the_command_line_only_parses_and_dispatches():
    assert len(MODULES["experiments.cli"].read_text("utf-8").splitlines()) <= 250


def test_the_facade_names_only_public_objects_that_exist():
    import clm_sim
    for name in clm_sim.__all__:
        assert getattr(clm_sim, name) is not None, name


def test_physics_import_loads_no_higher_layer_nor_heavy_library():
    code = ("import sys, clm_sim.plant, clm_sim.loop, clm_sim.records.read, "
            "clm_sim.records.write; "
            "bad = [m for m in sys.modules if m.split('.')[0] in "
            "('controllers', 'experiments', 'torch', 'matplotlib')]; print(bad)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         cwd=ROOT, check=True).stdout.strip()
    assert out == "[]", out


@pytest.mark.parametrize("modules, absent", [
    # what a sweep task's worker imports before its first task, and what every command imports
    # before it can refuse a bad config (a PID design loads control when a PID is designed)
    ("experiments.sweeps.run, experiments.runner, experiments.config, experiments.table",
     ("torch", "control", "matplotlib", "numba", "scipy.signal", "scipy.stats",
      "scipy.special")),
    # what a run imports to prepare its PGNN fits before it starts their worker pool
    ("controllers.pgnn, controllers.pgnn.data, controllers.pgnn.starts, "
     "experiments.processes.workers",
     ("torch", "control", "matplotlib", "scipy.signal", "scipy.stats")),
])
def test_start_up_imports_load_no_library_they_do_not_use(modules, absent):
    """Every spawned worker and command line process imports these first: a library imported
    at module level here is paid once per process (control with pyplot, scipy.signal with
    scipy.stats, torch: seconds), where the functions that use it import it themselves."""
    code = (f"import sys, {modules}; "
            f"print([m for m in {absent!r} if m in sys.modules])")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         cwd=ROOT, check=True).stdout.strip()
    assert out == "[]", out


def test_finding_the_study_kinds_loads_no_study():
    """``clm-sim study`` finds every kind before it reads the config's: the walk imports each
    study package's ``__init__.py`` only, never a study module nor the libraries they load."""
    code = ("import sys; from experiments.studies.runner import declared; declared(); "
            "print([m for m in sys.modules if m.endswith(('.study', '.benchmark')) "
            "or m.split('.')[0] in ('torch', 'matplotlib', 'control') "
            "or m in ('scipy.signal', 'scipy.stats')])")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         cwd=ROOT, check=True).stdout.strip()
    assert out == "[]", out


@pytest.mark.parametrize("module", sorted(MODULES))
def test_no_library_file_holds_more_than_one_sitting(module):
    """A module is read in one sitting (STYLE.md): at most 500 lines; a longer one holds more
    than one job and is cut by job."""
    lines = len(MODULES[module].read_text("utf-8").splitlines())
    assert lines <= 500, f"{MODULES[module].relative_to(ROOT)}: {lines} lines"
