"""What runs inside an FMU, derived from the imports (never a hand list).

An FMU of this project bundles its model's Python packages (``fmu_build.build``) and is stale when one of
the sources it runs changes (``fmu_build.fmus.sources_hash``). Which sources those are follows from the code:
the gear FMU's model is the pure library ``gearcontact_fmu`` (its fidelities are loaded by name, so the
whole package counts) with ``fmu_runtime``; the drivetrain FMUs run ``drivetrain.models.fmishell`` and
whatever it imports, at any depth and inside functions too. :func:`fmu_modules` walks that import graph
(``ast``, no code is run); everything else of ``drivetrain`` (the CLI, scenes, the master, campaigns) is
host-only: editing it marks no FMU stale, and the FMUs do not carry it.
"""
from __future__ import annotations

import ast
import functools
from pathlib import Path

#: packages that run inside an FMU as a whole (the gear FMU's library, the FMI-side runtime)
WHOLE_PACKAGES = ("gearcontact_fmu", "fmu_runtime")
#: the entry point of the drivetrain FMUs' code (the rendered slave scripts import it)
DRIVETRAIN_ENTRY = "drivetrain.models.fmishell"


def package_modules(pkg_dirs: dict[str, Path]) -> dict[str, Path]:
    """{dotted module name: file} of every module of the packages (``__init__`` as the package)."""
    mods = {}
    for pkg, d in pkg_dirs.items():
        for f in sorted(Path(d).rglob("*.py")):
            rel = f.relative_to(d)
            if "__pycache__" in rel.parts:
                continue
            parts = [pkg, *rel.with_suffix("").parts]
            if parts[-1] == "__init__":
                parts = parts[:-1]
            mods[".".join(parts)] = f
    return mods


@functools.lru_cache(maxsize=4096)
def _import_statements(path: str, mtime_ns: int, size: int) -> tuple:
    """(level, module, names) of every import statement of the file, functions included: parsed once per
    version of the file (its modification time and size key the memo; staleness checks walk the graph often)."""
    out = []
    for node in ast.walk(ast.parse(Path(path).read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            out.append((None, None, tuple(a.name for a in node.names)))
        elif isinstance(node, ast.ImportFrom):
            out.append((node.level, node.module, tuple(a.name for a in node.names)))
    return tuple(out)


def imported_modules(name: str, path: Path, known) -> set[str]:
    """The modules of ``known`` that module ``name`` imports anywhere in its code (functions included)."""
    pkg = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
    st = Path(path).stat()
    found = set()
    for level, module, names in _import_statements(str(path), st.st_mtime_ns, st.st_size):
        if level is None:
            targets = list(names)
        else:
            base = module or ""
            if level:
                base = ".".join(pkg[:len(pkg) - level + 1] + ([module] if module else []))
            targets = [base] + [f"{base}.{a}" for a in names]
        found.update(t for t in targets if t in known and t != name)
    return found


def _with_parents(name: str) -> list[str]:
    parts = name.split(".")
    return [".".join(parts[:i]) for i in range(1, len(parts) + 1)]


def fmu_modules(pkg_dirs: dict[str, Path], mods: dict[str, Path] | None = None) -> set[str]:
    """Every module that can run inside one of our FMUs: the whole-package roots, the drivetrain entry
    point, and the closure of their imports (with the packages on each module's path, whose
    ``__init__`` runs at import). ``mods``: :func:`package_modules` of ``pkg_dirs`` when at hand."""
    mods = package_modules(pkg_dirs) if mods is None else mods
    todo = [m for m in mods if m.split(".")[0] in WHOLE_PACKAGES]
    if DRIVETRAIN_ENTRY in mods:
        todo.append(DRIVETRAIN_ENTRY)
    seen: set[str] = set()
    while todo:
        m = todo.pop()
        if m in seen:
            continue
        seen.add(m)
        todo.extend(p for p in _with_parents(m) if p in mods and p not in seen)
        todo.extend(imported_modules(m, mods[m], mods) - seen)
    return seen


def fmu_files(pkg_dirs: dict[str, Path]) -> list[Path]:
    """The source files of :func:`fmu_modules`, sorted."""
    mods = package_modules(pkg_dirs)
    return sorted(mods[m] for m in fmu_modules(pkg_dirs, mods))
