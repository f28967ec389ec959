"""The house rules that a review can check mechanically (docs/ARCHITECTURE.md).

- The module import graph of src/, with imports inside functions counted, has no cycle.
- The pure library of the pair (gearcontact_fmu outside slaves/) never imports drivetrain, pythonfmu,
  the CLI or plotting.
- The native FMU builders read the FMUs' declarations in the library, never a pythonfmu slave.
- Only the command line (drivetrain.cli) and the plotting module (drivetrain.run.outputs) print.
"""
import ast
import functools
import re
from pathlib import Path

from drivetrain.fmu_build.bundle import imported_modules, package_modules

SRC = Path(__file__).resolve().parents[2] / "src"


@functools.cache
def _source(path: Path) -> str:
    return path.read_text()


@functools.cache
def _tree(path: Path) -> ast.Module:
    """The parsed module (read once per test run: the checks only walk it, none edits it)."""
    return ast.parse(_source(path))


def _modules() -> dict[str, Path]:
    """{dotted name: file} of every module of src/ (the walk the FMU bundle rule uses too)."""
    return package_modules({p.name: p for p in SRC.iterdir() if (p / "__init__.py").is_file()})


def _imports(name: str, path: Path, mods: dict) -> set[str]:
    """Every module of src/ that ``name`` imports, at any depth of its code (functions included)."""
    return imported_modules(name, path, mods)


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
        tree = _tree(p)
        for node in ast.walk(tree):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module or ""] if isinstance(node, ast.ImportFrom) and not node.level else [])
            for n in names:
                if n.split(".")[0] in ("drivetrain", "pythonfmu", "matplotlib") or ".slaves" in n:
                    bad.append(f"{m} imports {n}")
    assert not bad, bad


def test_only_the_cli_and_the_plots_print():
    allowed = {"drivetrain.cli", "drivetrain.run.outputs"}
    found = []
    for m, p in _modules().items():
        if m in allowed:
            continue
        for node in ast.walk(_tree(p)):
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "print":
                found.append(f"{m}:{node.lineno}")
    assert not found, "print() outside the CLI: " + ", ".join(found)


def test_only_the_plotting_module_imports_matplotlib():
    """Every plot goes through drivetrain.run.outputs (its backend, its layout), the only module that
    imports matplotlib; the others take their figures from it."""
    found = []
    for m, p in _modules().items():
        if m == "drivetrain.run.outputs":
            continue
        for node in ast.walk(_tree(p)):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
            found += [f"{m}:{node.lineno} imports {n}" for n in names if n.split(".")[0] == "matplotlib"]
    assert not found, "matplotlib outside drivetrain.run.outputs: " + ", ".join(found)


# ------------------------------------------------------------------------------------------------
# the wings of drivetrain (docs/ARCHITECTURE.md): each imports only its own wing and those below it
# ------------------------------------------------------------------------------------------------
#: bottom up; a wing may import any wing of a lower rank (the same rank: not each other)
WING_RANK = {
    "errors": 0, "system": 0,
    "rig": 1,
    "models": 2, "scene": 2,
    "fmu_build": 3,
    "cosim": 4,
    "run": 5,
    "campaigns": 6, "interop": 6,
    "cli": 7, "pytest_plugin": 7, "__main__": 8,
}


def _wing(module: str) -> str | None:
    parts = module.split(".")
    if parts[0] != "drivetrain" or len(parts) == 1:
        return None                      # the other packages, and drivetrain/__init__ (its version only)
    return parts[1]


def test_the_wings_import_downwards_only():
    mods = _modules()
    wings = {_wing(m) for m in mods} - {None}
    assert wings == set(WING_RANK), f"wings not ranked in this test: {sorted(wings ^ set(WING_RANK))}"
    bad = []
    for m, p in mods.items():
        a = _wing(m)
        if a is None:
            continue
        for n in _imports(m, p, mods):
            b = _wing(n)
            if b is not None and b != a and WING_RANK[b] >= WING_RANK[a]:
                bad.append(f"{m} ({a}, rank {WING_RANK[a]}) imports {n} ({b}, rank {WING_RANK[b]})")
    assert not bad, "imports against the wings' order:\n" + "\n".join(bad)


#: what loads a pythonfmu slave: pythonfmu itself, the slave script, the drivetrain slaves' shell and template
SLAVE_SIDE = ("pythonfmu", "gearcontact_fmu.slaves", "drivetrain.models.fmishell", "fmu_runtime.slave_template",
              "fmu_runtime.guard")
#: the declarations both builds read (plain data)
DECLARATIONS = ("gearcontact_fmu.fmu_variables", "drivetrain.models.fmu_variables", "fmu_runtime.declaration")


def _import_names(path: Path) -> list[tuple[str, list[str]]]:
    """(module, names taken from it) of every import statement of a file, functions included."""
    out = []
    for node in ast.walk(_tree(path)):
        if isinstance(node, ast.Import):
            out += [(a.name, []) for a in node.names]
        elif isinstance(node, ast.ImportFrom) and not node.level:
            out.append((node.module or "", [a.name for a in node.names]))
    return out


def _slave_side(module: str) -> bool:
    return any(module == s or module.startswith(s + ".") for s in SLAVE_SIDE)


def test_the_native_builders_read_the_declarations_not_a_slave():
    """The FMU slave apart from the library: the native builders (fmu_build.native_gear, .native_line) write
    their FMUs from the declarations in the library, which the pythonfmu slaves read too. Neither builder
    imports pythonfmu, a slave script, the slave shell or template, nor the pythonfmu builder's slave loaders
    (build.slave_class, build_fmu, build_all, find_slave_scripts); and the declarations, with every module of
    src they import (functions included), import nothing of the slave side."""
    mods = _modules()
    loaders = {"slave_class", "build_fmu", "build_all", "find_slave_scripts"}
    bad = []
    for m in ("drivetrain.fmu_build.native_gear", "drivetrain.fmu_build.native_line"):
        for module, names in _import_names(mods[m]):
            if _slave_side(module):
                bad.append(f"{m} imports {module}")
            bad += [f"{m} imports {module}.{n}" for n in names if n in loaders or _slave_side(f"{module}.{n}")]
    seen, todo = set(), list(DECLARATIONS)
    while todo:
        m = todo.pop()
        if m in seen:
            continue
        seen.add(m)
        bad += [f"{m} (imported by a declaration) imports {module}" for module, _ in _import_names(mods[m])
                if _slave_side(module)]
        todo += sorted(_imports(m, mods[m], mods))
    assert len(seen) > 10, sorted(seen)               # the walk went through the declarations' imports
    assert not bad, "the native build reaches the pythonfmu slave side:\n" + "\n".join(bad)


def test_drivetrain_has_no_flat_room():
    """Only the vocabulary (errors, system) and the entry points live at the package's top."""
    top = sorted(p.name for p in (SRC / "drivetrain").glob("*.py"))
    assert top == ["__init__.py", "__main__.py", "cli.py", "errors.py", "pytest_plugin.py",
                   "system.py"], top


# ------------------------------------------------------------------------------------------------
# functions a reader can hold, records with names
# ------------------------------------------------------------------------------------------------
MAX_FUNCTION_LINES = 120
MAX_POSITIONAL = 12


def _functions(tree):
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            yield node


def _is_kernel(node, source: str) -> bool:
    """An @njit/@jit function, or one the module compiles with njit(name) or njit(signature, ...)(name)."""
    for d in node.decorator_list:
        f = d.func if isinstance(d, ast.Call) else d
        name = f.attr if isinstance(f, ast.Attribute) else getattr(f, "id", "")
        if name in ("njit", "jit"):
            return True
    name = re.escape(node.name)
    return re.search(rf"jit\(\s*{name}\b|jit\([^()]*\)\(\s*{name}\s*\)", source) is not None


def test_no_function_over_120_lines_but_kernels_that_say_why():
    long = []
    for m, p in _modules().items():
        source = _source(p)
        for fn in _functions(_tree(p)):
            n = fn.end_lineno - fn.lineno + 1
            if n <= MAX_FUNCTION_LINES:
                continue
            doc = ast.get_docstring(fn) or ""
            if _is_kernel(fn, source) and "Long kernel:" in doc:
                continue
            long.append(f"{m}.{fn.name}: {n} lines")
    assert not long, ("functions over 120 lines (a numba kernel may stay long when its docstring says why, "
                      "'Long kernel: ...'):\n" + "\n".join(long))


def test_no_wide_positional_record_crosses_a_module():
    """A record of more than 12 fields travels with names: no tuple of more than 12 values is returned or
    unpacked, and no call passes more than 12 positional arguments to a function of another module."""
    mods = _modules()
    found = []
    for m, p in mods.items():
        tree = _tree(p)
        imported = set()                 # names bound by from-imports of src modules, and module aliases
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and (node.level or (node.module or "").split(".")[0] in
                                                     ("drivetrain", "gearcontact_fmu", "fmu_runtime")):
                imported.update(a.asname or a.name for a in node.names)
            elif isinstance(node, ast.Import):
                imported.update((a.asname or a.name).split(".")[0] for a in node.names
                                if a.name.split(".")[0] in ("drivetrain", "gearcontact_fmu", "fmu_runtime"))
        for node in ast.walk(tree):
            if isinstance(node, ast.Return) and isinstance(node.value, ast.Tuple) \
                    and len(node.value.elts) > MAX_POSITIONAL:
                found.append(f"{m}:{node.lineno}: returns a {len(node.value.elts)}-tuple")
            if isinstance(node, (ast.Assign, ast.For)):
                targets = node.targets if isinstance(node, ast.Assign) else [node.target]
                for t in targets:
                    if isinstance(t, (ast.Tuple, ast.List)) and len(t.elts) > MAX_POSITIONAL:
                        found.append(f"{m}:{node.lineno}: unpacks {len(t.elts)} values")
            if isinstance(node, ast.Call) and len(node.args) > MAX_POSITIONAL:
                f = node.func
                root = f
                while isinstance(root, ast.Attribute):
                    root = root.value
                if isinstance(root, ast.Name) and root.id in imported:
                    found.append(f"{m}:{node.lineno}: passes {len(node.args)} positional arguments to "
                                 f"{ast.unparse(f)}")
    assert not found, "wide positional records:\n" + "\n".join(found)


# ------------------------------------------------------------------------------------------------
# what an FMU bundles: derived from the imports
# ------------------------------------------------------------------------------------------------
def _copy_packages(tmp_path):
    import shutil

    dirs = {}
    for pkg in ("drivetrain", "gearcontact_fmu", "fmu_runtime"):
        dirs[pkg] = tmp_path / pkg
        shutil.copytree(SRC / pkg, dirs[pkg], ignore=shutil.ignore_patterns("__pycache__", "*.nbi", "*.nbc",
                                                                            "seed_maps"))
    return dirs


def test_fmus_run_the_models_and_the_pure_library_only():
    from drivetrain.fmu_build.bundle import fmu_modules

    dirs = {pkg: SRC / pkg for pkg in ("drivetrain", "gearcontact_fmu", "fmu_runtime")}
    inside = fmu_modules(dirs)
    assert {"drivetrain.models.fmishell", "drivetrain.models.components", "drivetrain.rig.data",
            "drivetrain.system", "drivetrain.errors", "gearcontact_fmu.stage", "gearcontact_fmu.slaves.GearContact",
            "fmu_runtime.guard"} <= inside
    host_only = {m for m in _modules() if m.startswith("drivetrain") and m not in inside}
    for m in ("drivetrain.cli", "drivetrain.cosim.master", "drivetrain.cosim", "drivetrain.fmu_build.build",
              "drivetrain.fmu_build.fmus", "drivetrain.campaigns.validation",
              "drivetrain.run.runner", "drivetrain.scene.load", "drivetrain.interop.ssp"):
        assert m in host_only, m


def test_editing_a_host_only_module_marks_no_fmu_stale(tmp_path, monkeypatch):
    """The staleness hash covers what runs inside an FMU: an edit of the master, the validation, the CLI
    or a scene module leaves it as it is; an edit of a model the FMUs run changes it."""
    from drivetrain.fmu_build import fmus

    dirs = _copy_packages(tmp_path)
    monkeypatch.setattr(fmus, "_package_dirs", lambda: dirs)
    before = fmus.sources_hash()
    for rel in ("cosim/master.py", "campaigns/validation.py", "cli.py", "scene/load.py", "run/runner.py"):
        f = dirs["drivetrain"] / rel
        f.write_text(f.read_text() + "\n# an edit\n")
    assert fmus.sources_hash() == before
    f = dirs["drivetrain"] / "models" / "components.py"
    f.write_text(f.read_text() + "\n# an edit\n")
    assert fmus.sources_hash() != before


def _documented_files() -> set[str]:
    """The source files docs/ARCHITECTURE.md's package tree names (paths under src/): a line's name column
    (before the description, which starts past column 28) is a folder ending in "/" or one or more files."""
    text = (SRC.parent / "docs" / "ARCHITECTURE.md").read_text()
    block = text.split("```")[1]
    folders: list[tuple[int, str]] = []
    files = set()
    for line in block.splitlines():
        indent = len(line) - len(line.lstrip())
        if not line.strip() or indent >= 28:
            continue
        name = re.match(r"[\w./-]+(?:,\s*[\w./-]+)*", line.strip()).group(0)
        if name.endswith("/") and "," not in name:
            folders = [(i, p) for i, p in folders if i < indent]
            base = folders[-1][1] if folders else ""
            folders.append((indent, name if name.startswith("src/") else base + name))
            continue
        base = next((p for i, p in reversed(folders) if i < indent), "")
        sub = ""
        for token in (t.strip() for t in name.split(",")):
            if not re.fullmatch(r"[\w./-]+\.(py|c|h)", token):
                continue
            if "/" in token:
                sub = token.rsplit("/", 1)[0] + "/"
                files.add(base + token)
            else:
                files.add(base + sub + token)
    return {f.removeprefix("src/") for f in files}


def test_the_architecture_tree_names_every_source_file():
    """docs/ARCHITECTURE.md's tree against the files: every module, C source and header under src/ is named
    there (package __init__ and __main__ aside), and every file it names exists."""
    every = {str(p.relative_to(SRC)) for ext in ("py", "c", "h") for p in SRC.rglob(f"*.{ext}")
             if "data" not in p.relative_to(SRC).parts}
    actual = {f for f in every if Path(f).name not in ("__init__.py", "__main__.py")}
    documented = _documented_files()
    assert not actual - documented, f"not in docs/ARCHITECTURE.md's tree: {sorted(actual - documented)}"
    assert not documented - every, f"named in docs/ARCHITECTURE.md's tree but missing: {sorted(documented - every)}"
