"""The shape of the code base: no import cycle between the parts of ``dqn_mine``, small
functions, and every document the code cites present in the repository."""

from __future__ import annotations

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "dqn_mine"
MAX_FUNCTION_LINES = 60


def _part(module: str) -> str | None:
    """The part of ``dqn_mine`` a dotted module name belongs to (a subpackage or a top-level
    module), or None for the package root and for modules outside ``dqn_mine``."""
    names = module.split(".")
    if names[0] != "dqn_mine" or len(names) < 2:
        return None
    return names[1]


def _imported_modules(tree: ast.AST) -> list[str]:
    """Every module an ``import`` names, function-level imports included (they still tie the
    two parts together); ``from dqn_mine import x`` counts as importing ``dqn_mine.x``."""
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            if node.module == "dqn_mine":
                found += [f"dqn_mine.{alias.name}" for alias in node.names]
            else:
                found.append(node.module)
    return found


def import_graph() -> dict[str, set[str]]:
    """part -> the other parts of ``dqn_mine`` it imports."""
    parts = {p.stem if p.is_file() else p.name for p in PACKAGE.iterdir()
             if (p.suffix == ".py" and p.stem != "__init__") or (p / "__init__.py").exists()}
    graph: dict[str, set[str]] = {part: set() for part in parts}
    for path in PACKAGE.rglob("*.py"):
        source = _part("dqn_mine." + ".".join(path.relative_to(PACKAGE).with_suffix("").parts))
        if source is None or source == "__init__":
            continue
        for module in _imported_modules(ast.parse(path.read_text())):
            target = _part(module)
            if target in parts and target != source:
                graph[source].add(target)
    return graph


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One cycle of ``graph`` as a path that returns to its start, or None."""
    state: dict[str, str] = {}

    def visit(node: str, path: list[str]) -> list[str] | None:
        state[node] = "open"
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == "open":
                return path[path.index(nxt):] + [nxt]
            if nxt not in state:
                cycle = visit(nxt, path + [nxt])
                if cycle:
                    return cycle
        state[node] = "done"
        return None

    for start in sorted(graph):
        if start not in state:
            cycle = visit(start, [start])
            if cycle:
                return cycle
    return None


def test_the_cycle_finder_finds_cycles():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": set()}) is None


def test_no_import_cycle_between_the_parts_of_the_package():
    graph = import_graph()
    assert {"env", "replay", "agent", "system", "config"} <= set(graph)
    assert "system" not in graph["replay"] and "system" not in graph["agent"]
    assert find_cycle(graph) is None, f"import cycle: {' -> '.join(find_cycle(graph))}"


def _long_functions(path: Path) -> list[str]:
    tree = ast.parse(path.read_text())
    return [f"{path.relative_to(ROOT)}:{node.lineno} {node.name} "
            f"({node.end_lineno - node.lineno + 1} lines)"
            for node in ast.walk(tree)
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef))
            and node.end_lineno - node.lineno + 1 > MAX_FUNCTION_LINES]


def test_no_function_is_longer_than_sixty_lines_outside_the_benchmarks():
    sources = [p for p in sorted(PACKAGE.rglob("*.py")) if "bench" not in p.parts]
    sources += sorted((ROOT / "experiments").rglob("*.py"))
    too_long = [line for path in sources for line in _long_functions(path)]
    assert not too_long, "\n".join(too_long)


MAX_COMMENT_LINES = 12   # a longer story belongs in docs/, with the runs behind it


def _long_comment_blocks(path: Path) -> list[str]:
    """'path:line (n lines)' of every run of more than MAX_COMMENT_LINES comment lines."""
    found, run = [], 0
    lines = path.read_text().splitlines()
    for number, line in enumerate([*lines, ""], start=1):
        if line.strip().startswith("#"):
            run += 1
            continue
        if run > MAX_COMMENT_LINES:
            found.append(f"{path.relative_to(ROOT)}:{number - run} ({run} lines)")
        run = 0
    return found


def test_no_comment_block_is_longer_than_twelve_lines():
    too_long = [b for path in sorted(PACKAGE.rglob("*.py")) for b in _long_comment_blocks(path)]
    assert not too_long, "\n".join(too_long)


# A repository path in code or docs: docs/x.md, dqn_mine/env/tasks.py, tests/test_x.py, ...
CITED = re.compile(r"(?<![\w/.])"
                   r"((?:docs|dqn_mine|tests|experiments)/[\w./-]*\w\.(?:md|py|png|gif))")


def cited_paths() -> dict[str, list[str]]:
    """path -> the files citing it, over the code, the tests, the experiments and the docs."""
    files = [*PACKAGE.rglob("*.py"), *(ROOT / "tests").glob("*.py"),
             *(ROOT / "experiments").rglob("*.py"), *(ROOT / "docs").glob("*.md"),
             ROOT / "README.md", ROOT / "Makefile"]
    cited: dict[str, list[str]] = {}
    for path in files:
        if path == Path(__file__).resolve():   # this file's examples are not citations
            continue
        for match in CITED.findall(path.read_text()):
            cited.setdefault(match, []).append(str(path.relative_to(ROOT)))
    return cited


def test_every_cited_document_exists():
    cited = cited_paths()
    assert "README.md" in cited["docs/design.md"], "the README links the design page"
    missing = {path: where for path, where in cited.items() if not (ROOT / path).exists()}
    assert not missing, missing
