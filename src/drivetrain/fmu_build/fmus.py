"""FMUs on disk: build when missing or stale, the staleness stamp, extraction, model descriptions.

- ``default_fmu_dir()``: where FMUs are built and kept unless a caller names a directory (never the current
  folder): a source checkout's own ``fmus/``, else the user-level cache ``<cache_dir()>/fmus``.
- ``ensure_fmus(models, fmu_dir)``: the paths of the models' FMUs; a missing FMU, or one built from other
  package sources than the current ones (``sources_hash``: SHA-256 of the sources that run inside FMUs,
  recorded per model in the directory's stamp), is (re)built with ``drivetrain.fmu_build.build`` under a file
  lock, and the stamp is written (``record_built``, the one writer of the stamp). The stamp and the lock
  live in the user-level cache (``stamp_path``), keyed by the directory: an FMU directory holds FMUs only.
- ``extracted_dir(path)``: ``fmpy.extract`` once per FMU file and process, under a private root.
- ``load_fmu_info(path)``: the model description as plain data (``FMUInfo``, ``VarInfo``).
"""
from __future__ import annotations

import atexit
import functools
import hashlib
import json
import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Sequence

import drivetrain
import fmu_runtime
import gearcontact_fmu
from drivetrain.fmu_build.fmu_check import fmu_archive_problems
from drivetrain.fmu_build.bundle import fmu_files
from drivetrain.errors import ConfigurationError
from gearcontact_fmu.locks import cache_dir, file_lock
from gearcontact_fmu.params import FLANGE_QUANTITIES, FLANGE_UNITS

PORT_VARS = FLANGE_QUANTITIES       #: a port's variables <port>_phi, _w, _tau (gearcontact_fmu.params)
PORT_UNITS = FLANGE_UNITS
#: the energy counters every FMU of the project reports (the audit's inputs)
ENERGY_VARS = ("energy_supplied", "energy_stored", "energy_dissipated")
_UNIT_SYNONYMS = {"N·m": "N.m", "Nm": "N.m", "N*m": "N.m", "N m": "N.m", "rad.s-1": "rad/s", "1/s": "1/s"}


@dataclass(frozen=True)
class VarInfo:
    name: str
    vr: int
    type: str                 # Real | Integer | Boolean | String | Enumeration
    causality: str
    variability: str
    unit: str | None
    initial: str | None
    start: str | None = None  # the declared start value as written in the modelDescription

    @property
    def constant(self) -> bool:
        """A constant (variability "constant": e.g. a parameter a native build fixed): never set by a host."""
        return self.variability == "constant"


@dataclass
class FMUInfo:
    model: str
    path: Path
    guid: str
    model_identifier: str
    variables: dict[str, VarInfo]
    description: Any = None


_INFO_CACHE: dict[tuple[str, float], FMUInfo] = {}
_EXTRACT_CACHE: dict[tuple[str, float], str] = {}
_EXTRACT_ROOT: list[str] = []


def _norm_unit(u: str | None) -> str | None:
    return _UNIT_SYNONYMS.get(u, u) if u else u


def load_fmu_info(path: Path | str) -> FMUInfo:
    """Model description of an FMU (cached per file and modification time)."""
    import fmpy

    path = Path(path).resolve()
    key = (str(path), path.stat().st_mtime)
    info = _INFO_CACHE.get(key)
    if info is None:
        problems = fmu_archive_problems(path)      # a swapped or hostile file: named, before fmpy reads it
        if problems:
            raise ConfigurationError(problems)
        try:
            md = fmpy.read_model_description(str(path), validate=False)
        except Exception as exc:  # noqa: BLE001 - whatever the reader trips on, the file and the reason
            raise ConfigurationError(f"{path}: its model description cannot be read ({type(exc).__name__}: "
                                     f"{str(exc)[:160]})") from None
        if md.coSimulation is None:
            raise ConfigurationError(f"{path.name}: not a co-simulation FMU")
        variables = {}
        for v in md.modelVariables:
            unit = v.unit
            if unit is None and v.declaredType is not None:
                unit = getattr(v.declaredType, "unit", None)
            variables[v.name] = VarInfo(v.name, v.valueReference, v.type, v.causality, v.variability,
                                        _norm_unit(unit), v.initial, v.start)
        info = FMUInfo(md.modelName, path, md.guid, md.coSimulation.modelIdentifier, variables, md)
        _INFO_CACHE[key] = info
    return info


def _cleanup_extracted() -> None:
    for d in _EXTRACT_ROOT:
        shutil.rmtree(d, ignore_errors=True)


def remove_extracted() -> None:
    """Remove the FMUs unpacked by this process now (no instance of them may be alive), not at its exit: the
    command line does it before it says where the time went (0.1-0.3 s for the pythonfmu FMUs). A later
    run unpacks them again."""
    _cleanup_extracted()
    _EXTRACT_ROOT.clear()
    _EXTRACT_CACHE.clear()


def _extract_root() -> str:
    """A private directory for extracted FMUs whose path has no ``%``: pythonfmu 0.7.0's export library
    crashes the process in fmi2Instantiate when the resource path contains one (it is used as a printf
    format; measured: segmentation fault with TMPDIR=/tmp/a%n). The system temporary directory is used
    unless its path has a ``%``; then the user cache directory, then /tmp."""
    candidates = [None, os.path.join(os.path.expanduser("~"), ".cache", "drivetrain"), "/tmp"]
    for base in candidates:
        root = base if base is not None else tempfile.gettempdir()
        if "%" in os.path.abspath(root):
            continue
        try:
            os.makedirs(root, exist_ok=True)
            d = tempfile.mkdtemp(prefix="drivetrain_fmus_", dir=root)
        except OSError:
            continue
        if "%" not in d:
            return d
    raise ConfigurationError("no directory without '%' in its path to extract the FMUs into (pythonfmu "
                             "crashes on such resource paths); set TMPDIR to one")


def extracted_dir(path: Path | str) -> str:
    """``fmpy.extract`` once per FMU file (and modification time) per process."""
    import fmpy

    path = Path(path).resolve()
    key = (str(path), path.stat().st_mtime)
    d = _EXTRACT_CACHE.get(key)
    if d is None or not os.path.isdir(d):
        if not _EXTRACT_ROOT:
            _EXTRACT_ROOT.append(_extract_root())
            atexit.register(_cleanup_extracted)
        target = os.path.join(_EXTRACT_ROOT[0], f"{path.stem}_{len(_EXTRACT_CACHE)}")
        d = fmpy.extract(str(path), unzipdir=target)
        _EXTRACT_CACHE[key] = d
    return d


def _package_dirs() -> dict[str, Path]:
    return {"drivetrain": Path(drivetrain.__file__).parent, "gearcontact_fmu": Path(gearcontact_fmu.__file__).parent,
            "fmu_runtime": Path(fmu_runtime.__file__).parent}


@functools.lru_cache(maxsize=1)
def _sources_hash_cached(stamp: tuple) -> str:
    h = hashlib.sha256()
    dirs = _package_dirs()
    fmu_side = set(fmu_files(dirs))
    for pkg, d in sorted(dirs.items()):
        for f in sorted(d.rglob("*.py")):
            rel = f.relative_to(d)
            if f not in fmu_side:          # host-only (fmu_build.bundle: derived from the imports)
                continue
            h.update(f"{pkg}/{rel.as_posix()}\0".encode())
            h.update(f.read_bytes())
            h.update(b"\0")
    for f in _packaging_files():
        h.update(f"{f.name}\0".encode())
        h.update(f.read_bytes())
    return h.hexdigest()


def _packaging_files() -> list[Path]:
    """What the build puts into a pythonfmu FMU besides the package sources: the FMI wrapper (its C source and
    the FMI headers), the modelDescription writer and the documentation with its committed reference plots.
    A change to any of them rebuilds the FMUs as a change of the sources does."""
    from drivetrain.fmu_build.fmi_headers import COMMON_HEADERS, fmi_header_dir
    from drivetrain.fmu_build.fmi_wrapper import WRAPPER_SOURCE
    from drivetrain.fmu_build.fmu_docs import PLOT_DIR

    here = Path(__file__).parent
    return [WRAPPER_SOURCE, *(fmi_header_dir() / n for n in COMMON_HEADERS),
            *(here / f"{m}.py" for m in ("build", "fmi_headers", "fmi_wrapper", "fmu_docs")),
            *sorted(PLOT_DIR.glob("*.png"))]


def sources_hash() -> str:
    """SHA-256 of the package sources that run inside the FMUs (:func:`drivetrain.fmu_build.bundle.fmu_modules`)."""
    stamp = []
    for pkg, d in sorted(_package_dirs().items()):
        for f in sorted(d.rglob("*.py")):
            st = f.stat()
            stamp.append((str(f), st.st_mtime_ns, st.st_size))
    for f in _packaging_files():
        st = f.stat()
        stamp.append((str(f), st.st_mtime_ns, st.st_size))
    return _sources_hash_cached(tuple(stamp))


#: the suffix of an FMU directory's stamp file (in the user-level cache, :func:`stamp_path`)
STAMP_FILE = ".sources-hash.json"
_CHECKED: dict[str, set] = {}     # fmu_dir -> models found fresh (or built) in this process


def source_checkout() -> Path | None:
    """The root of the source checkout the package runs from (``<root>/src/drivetrain`` beside
    ``<root>/pyproject.toml``), or None for an installed package."""
    root = Path(drivetrain.__file__).resolve().parents[2]
    if (root / "pyproject.toml").is_file() and (root / "src" / "drivetrain").is_dir():
        return root
    return None


def default_fmu_dir() -> Path:
    """Where FMUs are built and kept unless a caller names a directory, wherever the code runs from: the
    source checkout's ``fmus/`` when the package runs from one (``<root>/src/drivetrain`` beside
    ``<root>/pyproject.toml``: the developer's, git-ignored, one per checkout so that two checkouts with
    different sources never rebuild each other's FMUs), else ``<cache_dir()>/fmus`` (an installed package:
    the user-level cache, like the contact maps and the native FMUs)."""
    root = source_checkout()
    return root / "fmus" if root is not None else cache_dir() / "fmus"


def fmu_dir_or_default(fmu_dir: str | Path | None) -> Path:
    """``fmu_dir`` as a path; None: :func:`default_fmu_dir`."""
    return Path(fmu_dir) if fmu_dir is not None else default_fmu_dir()


def stamp_path(fmu_dir: str | Path) -> Path:
    """The staleness stamp of an FMU directory, in the user-level cache (its lock: the same path with
    ``.lock``): keyed by the directory's absolute path, so that the directory itself holds only FMUs."""
    d = Path(fmu_dir).resolve()
    key = hashlib.sha256(str(d).encode()).hexdigest()[:16]
    return cache_dir() / "fmu-stamps" / f"{d.name or 'root'}-{key}{STAMP_FILE}"


def _lock_path(fmu_dir: Path) -> Path:
    return stamp_path(fmu_dir).with_suffix(".lock")


def _read_stamp(fmu_dir: Path) -> dict:
    try:
        return json.loads(stamp_path(fmu_dir).read_text())
    except (OSError, ValueError):
        return {}


def stale_models(models: Sequence[str], fmu_dir: Path | str) -> list[str]:
    """Models whose FMU is missing in fmu_dir or was built from other package sources."""
    fmu_dir = Path(fmu_dir)
    current = sources_hash()
    stamp = _read_stamp(fmu_dir)
    return [m for m in dict.fromkeys(models)
            if not (fmu_dir / f"{m}.fmu").is_file() or stamp.get(m) != current]


def ensure_fmus(models: Sequence[str], fmu_dir: Path | str | None = None, build: bool = True,
                log: Callable[[str], None] | None = None) -> dict[str, Path]:
    """Paths of the FMUs of ``models``, building missing or stale ones with ``build_all`` (``fmu_dir`` None:
    :func:`default_fmu_dir`)."""
    fmu_dir = fmu_dir_or_default(fmu_dir)
    models = list(dict.fromkeys(models))
    if build:
        # checked once per process and directory: the package code this process runs (FMUs use the
        # installed packages in a Python host) does not change under it, so neither should its FMUs
        key = str(fmu_dir.resolve())
        fresh = _CHECKED.setdefault(key, set())
        todo_check = [m for m in models if m not in fresh or not (fmu_dir / f"{m}.fmu").is_file()]
    if build and todo_check:
        with file_lock(_lock_path(fmu_dir)):
            todo = stale_models(todo_check, fmu_dir)
            if todo:
                current = sources_hash()
                try:
                    from drivetrain.fmu_build.build import build_all
                except ImportError as exc:
                    missing = [m for m in todo if not (fmu_dir / f"{m}.fmu").is_file()]
                    if missing:
                        raise ConfigurationError(
                            [f"FMU {fmu_dir / (m + '.fmu')} is missing and cannot be built "
                             f"(drivetrain.fmu_build.build unavailable: {exc})" for m in missing]) from None
                    if log:
                        log(f"FMUs {todo} may be stale; cannot rebuild ({exc}); using them as they are")
                else:
                    if log:
                        log(f"building FMUs {todo} into {fmu_dir} (missing or built from other sources)")
                    built = build_all(str(fmu_dir), only=todo)
                    _write_stamp(fmu_dir, built, current)
            fresh.update(m for m in todo_check if (fmu_dir / f"{m}.fmu").is_file())
    paths = {}
    missing = []
    for m in models:
        p = fmu_dir / f"{m}.fmu"
        if p.is_file():
            paths[m] = p.resolve()
        else:
            missing.append(f"FMU for model {m!r} not found: {p}")
    if missing:
        raise ConfigurationError(missing)
    return paths


def _write_stamp(fmu_dir: Path, paths: Sequence[str | Path], current: str) -> None:
    """Record ``current`` as the sources hash of these FMU files (the caller holds the build lock)."""
    stamp = _read_stamp(fmu_dir)
    for p in paths:
        p = Path(p)
        if p.suffix == ".fmu" and p.is_file() and p.parent.resolve() == fmu_dir.resolve():
            stamp[p.stem] = current
    path = stamp_path(fmu_dir)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + f".{os.getpid()}")
    tmp.write_text(json.dumps(stamp, indent=1, sort_keys=True))
    os.replace(tmp, path)


def record_built(fmu_dir: str | Path | None, paths: Sequence[str | Path]) -> None:
    """Record that these FMUs were just built from the current sources (staleness stamp; ``fmu_dir`` None:
    :func:`default_fmu_dir`)."""
    fmu_dir = fmu_dir_or_default(fmu_dir)
    current = sources_hash()
    with file_lock(_lock_path(fmu_dir)):
        _write_stamp(fmu_dir, paths, current)
