"""Maintainers: the import graph of the ``doabench`` package, from its source alone (``ast``, nothing imported),
and the import cycles of it and of ``baselines/`` (``doabench_baselines``).

Every ``import`` / ``from ... import`` statement counts, at any depth (inside functions, ``if``
blocks, ``try``): a lazy import still ties the two modules together. ``TYPE_CHECKING`` blocks
count too. ``from pkg import name`` is an edge to ``pkg.name`` when that is a module, else to ``pkg``.

    python scripts/import_graph.py            # strongly connected components (cycles) of both, exit 1 if any
    python scripts/import_graph.py --packages # package-level graph as plain text
    python scripts/import_graph.py --mermaid  # its transitive reduction as a Mermaid flowchart
    python scripts/import_graph.py --modules  # module-level graph as plain text

tests/test_architecture.py imports this file and fails when a cycle appears.
"""
from __future__ import annotations

import ast
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = "doabench"
#: the folders whose modules must import one another without a cycle: doabench and its learned
#: trackers (baselines/ installs as doabench_baselines; its modules import one another relatively)
CYCLE_CHECKED = ("doabench", "baselines")


def module_files(root: Path = ROOT, package: str = PACKAGE) -> dict[str, Path]:
    """``{dotted module name: file}`` for every module of ``package`` under ``root``."""
    out = {}
    for path in sorted((root / package).rglob("*.py")):
        parts = list(path.relative_to(root).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


def _resolve_relative(module: str, is_package: bool, level: int, name: str | None) -> str:
    base = module.split(".")
    if not is_package:
        base = base[:-1]
    if level > 1:
        base = base[: len(base) - (level - 1)]
    return ".".join(base + ([name] if name else []))


def imports_of(module: str, path: Path, modules: dict[str, Path]) -> set[str]:
    """The modules of the package that ``module`` imports, anywhere in its body."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    is_package = path.name == "__init__.py"
    targets: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                targets.add(alias.name)
        elif isinstance(node, ast.ImportFrom):
            base = (_resolve_relative(module, is_package, node.level, node.module)
                    if node.level else (node.module or ""))
            for alias in node.names:
                sub = f"{base}.{alias.name}"
                targets.add(sub if sub in modules else base)
    out = set()
    for target in targets:
        # `import a.b.c` imports a, a.b and a.b.c; the deepest known module is the edge.
        parts = target.split(".")
        while parts and ".".join(parts) not in modules:
            parts.pop()
        if parts:
            name = ".".join(parts)
            if name != module:
                out.add(name)
    return out


def module_graph(root: Path = ROOT, package: str = PACKAGE) -> dict[str, set[str]]:
    modules = module_files(root, package)
    return {name: imports_of(name, path, modules) for name, path in modules.items()}


def strongly_connected_components(graph: dict[str, set[str]]) -> list[list[str]]:
    """Tarjan's algorithm (iterative); components of more than one module, or a self-loop."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    on_stack: set[str] = set()
    stack: list[str] = []
    components: list[list[str]] = []
    counter = 0
    for start in sorted(graph):
        if start in index:
            continue
        work = [(start, iter(sorted(graph[start])))]
        index[start] = low[start] = counter
        counter += 1
        stack.append(start)
        on_stack.add(start)
        while work:
            node, children = work[-1]
            advanced = False
            for child in children:
                if child not in graph:
                    continue
                if child not in index:
                    index[child] = low[child] = counter
                    counter += 1
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph[child]))))
                    advanced = True
                    break
                if child in on_stack:
                    low[node] = min(low[node], index[child])
            if advanced:
                continue
            work.pop()
            if work:
                parent = work[-1][0]
                low[parent] = min(low[parent], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                if len(component) > 1 or node in graph[node]:
                    components.append(sorted(component))
    return sorted(components, key=lambda c: (-len(c), c))


def cycles(root: Path = ROOT, package: str = PACKAGE) -> list[list[str]]:
    return strongly_connected_components(module_graph(root, package))


def package_of(module: str, package: str = PACKAGE) -> str:
    """``doabench.envs.env`` → ``envs``; top-level modules keep their name; the root is ``doabench``."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else package


def package_graph(root: Path = ROOT, package: str = PACKAGE) -> dict[str, set[str]]:
    out: dict[str, set[str]] = {}
    for module, targets in module_graph(root, package).items():
        src = package_of(module, package)
        out.setdefault(src, set())
        for target in targets:
            dst = package_of(target, package)
            if dst != src:
                out[src].add(dst)
    return out


def transitive_reduction(graph: dict[str, set[str]]) -> dict[str, set[str]]:
    """The fewest edges with the same reachability (``graph`` must be acyclic): ``a -> c`` goes
    when ``a`` reaches ``c`` through another of its imports. For a readable picture only."""
    def reach(start: str) -> set[str]:
        seen: set[str] = set()
        todo = [start]
        while todo:
            for nxt in graph.get(todo.pop(), ()):
                if nxt not in seen:
                    seen.add(nxt)
                    todo.append(nxt)
        return seen

    reachable = {node: reach(node) for node in graph}
    return {node: {t for t in targets if not any(t in reachable.get(o, ()) for o in targets if o != t)}
            for node, targets in graph.items()}


def render_text(graph: dict[str, set[str]]) -> str:
    width = max(len(name) for name in graph)
    return "\n".join(f"{name:<{width}} -> {', '.join(sorted(graph[name])) or '(nothing)'}"
                     for name in sorted(graph))


def render_mermaid(graph: dict[str, set[str]]) -> str:
    lines = ["flowchart LR"]
    for name in sorted(graph):
        for target in sorted(graph[name]):
            lines.append(f"    {name.replace('doabench', 'root')} --> {target.replace('doabench', 'root')}")
    return "\n".join(lines)


def main(argv: list[str]) -> int:
    if "--packages" in argv:
        print(render_text(package_graph()))
        return 0
    if "--mermaid" in argv:
        print(render_mermaid(transitive_reduction(package_graph())))
        return 0
    if "--modules" in argv:
        print(render_text(module_graph()))
        return 0
    found = False
    for package in CYCLE_CHECKED:
        graph = module_graph(ROOT, package)
        for component in strongly_connected_components(graph):
            found = True
            members = set(component)
            print(f"cycle of {len(component)} modules:")
            for module in component:
                inside = sorted(graph[module] & members)
                print(f"  {module} -> {', '.join(inside)}")
    if not found:
        print(f"no import cycles in {', '.join(CYCLE_CHECKED)}")
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
