"""The package's shape: no import cycle (type-only imports included), read from the source."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# Where each part of the installed package lives in the tree (pyproject's package-dir).
FOLDERS = {
    "itnet": "itnet",
    "itnet.model": "model",
    "itnet.export": "export",
    "itnet.service": "service",
    "itnet.clients": "clients",
    "itnet.scale": "scale",
}


def _modules() -> dict[str, Path]:
    """Every module of the package by its dotted name."""
    found: dict[str, Path] = {}
    for package, folder in FOLDERS.items():
        for path in sorted((ROOT / folder).rglob("*.py")):
            parts = path.relative_to(ROOT / folder).with_suffix("").parts
            if parts[-1] == "__init__":
                parts = parts[:-1]
            name = ".".join((package, *parts))
            if package == "itnet" and name.split(".")[1:2] in (["model"], ["export"]):
                continue
            found[name] = path
    return found


def _imported(tree: ast.Module, name: str, is_package: bool) -> set[str]:
    """The dotted names a module imports at import time or for type checking (not inside
    functions, where an import runs only when called)."""
    names: set[str] = set()
    stack: list[ast.stmt] = list(tree.body)
    while stack:
        node = stack.pop()
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                package = name if is_package else name.rpartition(".")[0]
                for _ in range(node.level - 1):
                    package = package.rpartition(".")[0]
                base = f"{package}.{base}" if base else package
            names.add(base)
            names.update(f"{base}.{alias.name}" for alias in node.names)
        elif not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            for child in ast.iter_child_nodes(node):
                if isinstance(child, ast.stmt):
                    stack.append(child)
    return names


def import_graph() -> dict[str, set[str]]:
    """Module -> the package's modules it imports."""
    modules = _modules()
    graph: dict[str, set[str]] = {}
    for name, path in modules.items():
        tree = ast.parse(path.read_text())
        imported = _imported(tree, name, path.name == "__init__.py")
        graph[name] = {m for m in imported if m in modules and m != name}
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected parts of more than one module (Tarjan's algorithm, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    on_stack: set[str] = set()
    stack: list[str] = []
    found: list[list[str]] = []
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph[child]))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                part = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    part.append(member)
                    if member == node:
                        break
                if len(part) > 1:
                    found.append(sorted(part))
    return found


def test_the_cycle_finder_finds_a_planted_cycle() -> None:
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}, "e": set()}
    assert cycles(graph) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set()}) == []


def test_the_graph_sees_type_only_imports() -> None:
    tree = ast.parse(
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from itnet.pose.loop import X\n"
        "def f():\n    import itnet.scene\n"
    )
    names = _imported(tree, "itnet.pose.stages", False)
    assert "itnet.pose.loop" in names
    assert "itnet.scene" not in names  # inside a function: runs only when called


def test_no_import_cycle_in_the_package() -> None:
    graph = import_graph()
    assert len(graph) > 150  # every part of the package was read
    assert cycles(graph) == []


def test_the_build_library_has_no_command_line_of_its_own() -> None:
    """model/ and export/ are libraries: their commands are ``itnet``'s (``itnet fit`` ...)."""
    for folder in ("model", "export"):
        for path in sorted((ROOT / folder).rglob("*.py")):
            text = path.read_text()
            assert "__main__" not in text and "argparse.ArgumentParser(" not in text, path


def _functions(folder: str) -> list[tuple[Path, ast.FunctionDef | ast.AsyncFunctionDef]]:
    found = []
    for path in sorted((ROOT / folder).rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                found.append((path, node))
    return found


def _lines(node: ast.FunctionDef | ast.AsyncFunctionDef, body_only: bool) -> int:
    """A function's lines from its ``def`` (or, ``body_only``, from its first statement after
    the docstring) to its end."""
    body = node.body
    head = body[0]
    documented = isinstance(head, ast.Expr) and isinstance(head.value, ast.Constant)
    if body_only and len(body) > 1 and documented:
        body = body[1:]
    first = body[0].lineno if body_only else node.lineno
    return int(node.end_lineno or first) - first + 1


def test_functions_fit_on_a_screen() -> None:
    """No function of the product is over 80 lines; no command's body over 40 (it parses,
    calls one function of the library and prints)."""
    long = [f"{p.relative_to(ROOT)}:{n.lineno} {n.name}" for folder in
            ("itnet", "service", "scale", "clients") for p, n in _functions(folder)
            if _lines(n, body_only=False) > 80]  # fmt: skip
    assert long == []
    commands = [f"{p.name}:{n.lineno} {n.name}" for p, n in _functions("itnet/commands")
                if n.col_offset == 0 and _lines(n, body_only=True) > 40]  # fmt: skip
    assert commands == []
    assert len(_functions("itnet/commands")) > 50  # every command module was read
