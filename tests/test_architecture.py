"""The architecture, checked: no import cycles in doabench or baselines/ (imports inside functions
count), the import-linter contracts of pyproject.toml (layers; baselines through the public API
only; in baselines, the trackers above the weights catalog above the weights files), task kinds
loaded by entry point, and docs/architecture.md's graph equal to the tree's. See docs/architecture.md."""
from __future__ import annotations

import ast
import importlib.util
import re
import sys
from importlib import metadata
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _load_script():
    spec = importlib.util.spec_from_file_location("doabench_import_graph", ROOT / "scripts" / "import_graph.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


graph = _load_script()


def _pyproject() -> dict:
    try:
        import tomllib
    except ModuleNotFoundError:  # Python 3.10
        import tomli as tomllib
    return tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))


@pytest.mark.parametrize("package", graph.CYCLE_CHECKED)
def test_no_import_cycles(package):
    """No cycle in doabench, nor in baselines/ (doabench_baselines: its weights catalog builds on
    the weights files' module, which never imports it back, not even inside a function)."""
    found = graph.cycles(ROOT, package)
    assert not found, "import cycles (python scripts/import_graph.py shows the edges): " + "; ".join(
        " <-> ".join(c) for c in found)


def test_cycle_checker_sees_lazy_imports(tmp_path):
    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("from pkg.sub import b\n")
    (pkg / "sub" / "__init__.py").write_text("")
    (pkg / "sub" / "b.py").write_text("def f():\n    from .. import c\n")
    (pkg / "c.py").write_text("def g():\n    if True:\n        import pkg.a\n")
    (pkg / "d.py").write_text("from pkg import a\n")  # into the cycle, not part of it
    assert graph.cycles(tmp_path, "pkg") == [["pkg.a", "pkg.c", "pkg.sub.b"]]


def test_import_contracts():
    importlinter = pytest.importorskip("importlinter.cli", reason="import-linter is in the test extra")
    code = importlinter.lint_imports(config_filename=str(ROOT / "pyproject.toml"), no_cache=True, no_logo=True)
    assert code == 0, "an import-linter contract is broken (run lint-imports for the report)"


def _top_level_imports(path: Path) -> set[str]:
    out = set()
    for node in ast.parse(path.read_text(encoding="utf-8")).body:
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out.add(node.module)
        elif isinstance(node, ast.Import):
            out.update(alias.name for alias in node.names)
    return out


def test_baselines_import_only_the_public_api():
    """What baselines/ may import: ``doabench`` and the modules ``doabench/__init__.py`` re-exports
    from (at top level). Checked from the source, so a new doabench module is covered too."""
    public = {"doabench"} | {m for m in _top_level_imports(ROOT / "doabench" / "__init__.py")
                             if m.startswith("doabench.")}
    bad = []
    for path in sorted((ROOT / "baselines").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module] if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module
                     else [])
            bad += [f"{path.name}:{node.lineno} {n}" for n in names
                    if (n == "doabench" or n.startswith("doabench.")) and n not in public]
    assert not bad, f"baselines/ reaches past doabench's public API: {bad}"


def test_version_has_one_source():
    from doabench import __version__
    from doabench._version import __version__ as version

    assert __version__ == version == _pyproject()["project"]["version"]
    offenders = [f"{m}" for m, path in graph.module_files().items() if m != "doabench"
                 for node in ast.walk(ast.parse(path.read_text(encoding="utf-8")))
                 if isinstance(node, ast.ImportFrom) and node.module == "doabench" and node.level == 0
                 and any(a.name == "__version__" for a in node.names)]
    assert not offenders, f"import __version__ from doabench._version, not the package root: {offenders}"


def test_task_kinds_come_from_entry_points_only():
    """The registry and the episode-source module name no task kind; the kinds of pyproject.toml
    are the ones the installed metadata declares (a stale install fails here, not in a run)."""
    for name in ("registry.py", "sources.py"):
        tree = ast.parse((ROOT / "doabench" / "envs" / name).read_text(encoding="utf-8"))
        imported = {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.module}
        imported |= {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
        assert not {m for m in imported if m.startswith(("doabench.datasets", "doabench.locata",
                                                          "doabench.envs.simulated"))}, name
        strings = {n.value for n in ast.walk(tree) if isinstance(n, ast.Constant) and isinstance(n.value, str)}
        assert not strings & {"simulated", "locata", "dataset", "file:"}, f"{name} names a task kind"
    entry_points = _pyproject()["project"]["entry-points"]
    for group in ("doabench.task_kinds", "doabench.task_prefixes"):
        installed = {ep.name: ep.value for ep in metadata.entry_points(group=group)}
        declared = entry_points[group]
        assert {k: installed.get(k) for k in declared} == declared, (
            f"the installed metadata of {group} is stale; reinstall: pip install -e .")


def test_every_builtin_task_kind_loads():
    from doabench.envs.registry import available_tasks
    from doabench.envs.sources import available_task_kinds

    kinds = {spec.kind for spec in available_tasks().values()}
    assert kinds <= set(available_task_kinds())
    for ep in metadata.entry_points(group="doabench.task_kinds"):
        assert callable(ep.load()), ep


def test_architecture_doc_shows_the_real_graph():
    text = (ROOT / "docs" / "architecture.md").read_text(encoding="utf-8")
    packages = graph.package_graph()
    for name, lang, expected in (
            ("import-graph", "mermaid", graph.render_mermaid(graph.transitive_reduction(packages))),
            ("import-table", "text", graph.render_text(packages))):
        match = re.search(rf"<!-- {name}:begin -->\n```{lang}\n(.*?)```\n<!-- {name}:end -->", text, re.S)
        assert match, f"docs/architecture.md lacks the generated block {name}"
        assert match.group(1).strip() == expected.strip(), (
            f"docs/architecture.md's {name} is out of date: python scripts/import_graph.py "
            f"{'--mermaid' if lang == 'mermaid' else '--packages'}")


def test_layers_in_the_doc_match_the_contract():
    layers = _pyproject()["tool"]["importlinter"]["contracts"][0]["layers"]
    text = (ROOT / "docs" / "architecture.md").read_text(encoding="utf-8")
    for number, layer in enumerate(layers, 1):
        names = ", ".join(f"`{n.strip()}`" for n in layer.split("|"))
        assert f"| {number} | {names} |" in text, f"docs/architecture.md's layer table lacks layer {number}: {layer}"


def test_every_package_is_in_the_distribution():
    """setup.py discovers doabench's packages and adds the two renamed folders (baselines/ installs
    as doabench_baselines and tasks/ as doabench.task_specs, pyproject.toml's package-dir): every
    folder with an ``__init__.py`` must be among them, or a non-editable install would lack it."""
    import runpy

    try:
        import tomllib
    except ImportError:  # Python 3.10: the test extra's tomli
        import tomli as tomllib

    tool = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    assert "packages" not in tool, "the packages come from setup.py's discovery, not a list in pyproject.toml"
    setup_py = runpy.run_path(str(ROOT / "setup.py"), run_name="doabench_setup")
    renamed = {v: k for k, v in tool["package-dir"].items()}
    assert sorted(renamed.values()) == sorted(setup_py["RENAMED_PACKAGES"])
    listed = set(setup_py["packages"](str(ROOT)))
    found = set()
    for init in [*(ROOT / "doabench").rglob("__init__.py"), *(ROOT / "baselines").rglob("__init__.py"),
                 ROOT / "tasks" / "__init__.py"]:
        folder = init.parent.relative_to(ROOT).as_posix()
        top, _, sub = folder.partition("/")
        found.add(renamed.get(folder) or (f"{renamed[top]}.{sub.replace('/', '.')}" if top in renamed else
                                          folder.replace("/", ".")))
    assert found == listed, {"missing": sorted(found - listed), "not a package": sorted(listed - found)}


def test_the_packaging_configuration_draws_no_setuptools_warning():
    """What setuptools warns about when it builds the package (``make demo``'s install): a licence
    given as a table instead of an SPDX string, and data folders without an ``__init__.py`` seen as
    packages left out of the build (they are, with include-package-data). So the data files are
    exactly package-data's, and that list must cover every file of the data folders."""
    from fnmatch import fnmatch

    project = _pyproject()
    assert isinstance(project["project"]["license"], str)
    assert any(r.replace(" ", "").startswith("setuptools>=77") for r in project["build-system"]["requires"])
    tool = project["tool"]["setuptools"]
    assert tool["include-package-data"] is False
    folders = {**{pkg: pkg.replace(".", "/") for pkg in tool["package-data"]},
               **{pkg: folder for pkg, folder in tool["package-dir"].items()}}
    shipped = {(Path(folders[pkg]) / pattern).as_posix() for pkg, patterns in tool["package-data"].items()
               for pattern in patterns}
    for data in ("baselines/weights", "doabench/data/speech", "doabench/results/schemas"):
        for path in (ROOT / data).iterdir():
            rel = path.relative_to(ROOT).as_posix()
            assert path.is_dir() or any(fnmatch(rel, p) for p in shipped), f"{rel} would not be installed"
