"""The house rules that a review can check mechanically (docs/ARCHITECTURE.md).

- The module import graph of src/, with imports inside functions counted, has no cycle.
- The pure library of the pair (gearcontact_fmu outside slaves/) never imports drivetrain, pythonfmu,
  the CLI or plotting.
- Only the command line (drivetrain.cli) and the plotting module (drivetrain.outputs) print.
"""
import ast
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src"


def _modules() -> dict[str, Path]:
    mods = {}
    for p in SRC.rglob("*.py"):
        parts = list(p.relative_to(SRC).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        mods[".".join(parts)] = p
    return mods


def _imports(name: str, path: Path, mods: dict) -> set[str]:
    """Every module of src/ that ``name`` imports, at any depth of its code (functions included)."""
    pkg = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        targets = []
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(pkg[:len(pkg) - node.level + 1] + ([node.module] if node.module else []))
            targets = [base] + [f"{base}.{a.name}" for a in node.names]
        out.update(t for t in targets if t in mods and t != name)
    return out


def test_import_graph_is_acyclic():
    mods = _modules()
    graph = {m: _imports(m, p, mods) for m, p in mods.items()}
    state: dict[str, int] = {}
    stack: list[str] = []
    cycles = []

    def visit(m):
        state[m] = 1
        stack.append(m)
        for n in sorted(graph[m]):
            if state.get(n) == 1:
                cycles.append(stack[stack.index(n):] + [n])
            elif n not in state:
                visit(n)
        stack.pop()
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m)
    assert not cycles, "import cycles:\n" + "\n".join(" -> ".join(c) for c in cycles)
    assert len(graph) > 30 and sum(map(len, graph.values())) > 80   # the walk saw the package


def test_pure_library_imports_no_host_side():
    mods = _modules()
    bad = []
    for m, p in mods.items():
        if not m.startswith("gearcontact_fmu") or ".slaves" in m:
            continue
        tree = ast.parse(p.read_text())
        for node in ast.walk(tree):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module or ""] if isinstance(node, ast.ImportFrom) and not node.level else [])
            for n in names:
                if n.split(".")[0] in ("drivetrain", "pythonfmu", "matplotlib") or ".slaves" in n:
                    bad.append(f"{m} imports {n}")
    assert not bad, bad


def test_only_the_cli_and_the_plots_print():
    allowed = {"drivetrain.cli", "drivetrain.outputs"}
    found = []
    for m, p in _modules().items():
        if m in allowed:
            continue
        for node in ast.walk(ast.parse(p.read_text())):
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "print":
                found.append(f"{m}:{node.lineno}")
    assert not found, "print() outside the CLI: " + ", ".join(found)
