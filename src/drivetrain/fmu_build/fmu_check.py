"""Is this file an FMU we can use: the archive and its model description checked before anything reads,
unpacks or loads it (issue 45: an FMU swapped in with ``--fmu``).

:func:`fmu_archive_problems` says, all at once, what is wrong with an FMU file:

- a zip archive (not truncated, within :data:`MAX_MEMBERS` entries and :data:`MAX_UNPACKED_BYTES` unpacked);
- every entry unpacks inside its folder: no absolute path, drive letter, ``..`` component or symbolic link;
- ``modelDescription.xml`` present, at most :data:`MAX_XML_BYTES`, without a DTD (no ``<!DOCTYPE``: an entity
  bomb or an external entity never reaches a parser), parsed (defusedxml when installed);
- FMI 2.0 co-simulation (``fmiVersion="2.0"``, a ``<CoSimulation>`` with its ``modelIdentifier``), a
  ``guid``, the model the caller expects (``modelName``);
- its variables named and their ``<ModelStructure>`` indices within them;
- the binary for this platform present, and carrying the model description's GUID when it carries any (our
  builds compile it in: an FMU whose description was swapped would fail at instantiation).

:func:`drivetrain.fmu_build.fmus.load_fmu_info` runs it on every FMU before fmpy reads one, so a swapped FMU is a
ConfigurationError naming the file and what was wrong, never a traceback from the reader or the loader.
"""
from __future__ import annotations

import re
import stat
import zipfile
from pathlib import Path, PurePosixPath

try:                                           # a hardened parser when installed; the DTD is refused either way
    from defusedxml import ElementTree as _ET  # type: ignore[import-not-found]
except ImportError:                            # pragma: no cover - depends on the environment
    import xml.etree.ElementTree as _ET

MAX_XML_BYTES = 16 * 1024 * 1024               #: a model description larger than this is not one of ours
MAX_MEMBERS = 10_000
MAX_UNPACKED_BYTES = 4 * 1024 ** 3             #: 4 GiB unpacked (a zip bomb is refused before unpacking)
_GUID_RE = re.compile(rb"[0-9a-fA-F]{8}-[0-9a-fA-F]{4}-[0-9a-fA-F]{4}-[0-9a-fA-F]{4}-[0-9a-fA-F]{12}")
_STRUCTURE = ("Outputs", "Derivatives", "InitialUnknowns")


def _platform_binary(identifier: str) -> str:
    from fmpy import platform, sharedLibraryExtension

    return f"binaries/{platform}/{identifier}{sharedLibraryExtension}"


def member_problems(zf: zipfile.ZipFile, where: str) -> list[str]:
    """Entries that would unpack outside their folder, or too many or too large to unpack."""
    problems = []
    infos = zf.infolist()
    if len(infos) > MAX_MEMBERS:
        return [f"{where}: {len(infos)} entries (at most {MAX_MEMBERS})"]
    total = sum(i.file_size for i in infos)
    if total > MAX_UNPACKED_BYTES:
        problems.append(f"{where}: {total} bytes unpacked (at most {MAX_UNPACKED_BYTES})")
    for i in infos:
        name = i.filename
        parts = PurePosixPath(name.replace("\\", "/")).parts
        if name.startswith(("/", "\\")) or re.match(r"^[A-Za-z]:", name) or ".." in parts or "\x00" in name:
            problems.append(f"{where}: entry {name[:120]!r} would unpack outside the FMU's folder")
        elif stat.S_ISLNK(i.external_attr >> 16):
            problems.append(f"{where}: entry {name[:120]!r} is a symbolic link")
    return problems


def _parse_description(text: bytes, where: str) -> tuple[object | None, list[str]]:
    """(root element, problems) of modelDescription.xml: bounded, no DTD, well-formed."""
    if len(text) > MAX_XML_BYTES:
        return None, [f"{where}: modelDescription.xml has {len(text)} bytes (at most {MAX_XML_BYTES})"]
    if re.search(rb"<!\s*(DOCTYPE|ENTITY)", text, re.IGNORECASE):
        return None, [f"{where}: modelDescription.xml declares a DTD or entities (<!DOCTYPE>): refused unread "
                      "(an FMI model description has none)"]
    try:
        return _ET.fromstring(text), []
    except Exception as exc:  # noqa: BLE001 - ParseError, defusedxml's refusals: named, whatever they are
        return None, [f"{where}: modelDescription.xml is not well-formed XML ({type(exc).__name__}: "
                      f"{str(exc)[:120]})"]


def description_problems(root, where: str, model: str | None) -> tuple[list[str], str | None, str | None]:
    """(problems, guid, modelIdentifier) of a parsed model description."""
    problems = []
    if root.tag != "fmiModelDescription":
        return [f"{where}: modelDescription.xml's root is <{root.tag[:40]}>, not <fmiModelDescription>"], None, None
    version = root.get("fmiVersion")
    if version != "2.0":
        problems.append(f"{where}: fmiVersion = {str(version)[:20]!r}: only FMI 2.0 FMUs are run")
    guid = root.get("guid")
    if not guid:
        problems.append(f"{where}: the model description has no guid")
    name = root.get("modelName")
    if model is not None and name != model:
        problems.append(f"{where}: an FMU of model {str(name)[:60]!r}, given for model {model!r}")
    cs = root.find("CoSimulation")
    ident = cs.get("modelIdentifier") if cs is not None else None
    if cs is None:
        problems.append(f"{where}: not a co-simulation FMU (no <CoSimulation>)")
    elif not ident or not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]{0,127}", ident):
        problems.append(f"{where}: <CoSimulation> modelIdentifier = {str(ident)[:60]!r}: expected a C identifier")
        ident = None
    mv = root.find("ModelVariables")
    variables = mv.findall("ScalarVariable") if mv is not None else []
    if not variables:
        problems.append(f"{where}: the model description declares no variables")
    nameless = sum(not v.get("name") for v in variables)
    if nameless:
        problems.append(f"{where}: {nameless} variables without a name")
    ms = root.find("ModelStructure")
    for section in _STRUCTURE if ms is not None else ():
        el = ms.find(section)
        for u in el.findall("Unknown") if el is not None else ():
            refs = [u.get("index")] + (u.get("dependencies") or "").split()
            for r in refs:
                if r is None or not r.isdigit() or not 1 <= int(r) <= len(variables):
                    problems.append(f"{where}: <ModelStructure><{section}> refers to variable {str(r)[:20]!r} of "
                                    f"{len(variables)} (a variable missing from the description?)")
                    break
    return problems, guid, ident


def fmu_archive_problems(path: Path | str, model: str | None = None) -> list[str]:
    """Everything wrong with an FMU file, before it is read, unpacked or loaded (the module docstring);
    ``model``: the model it must be (its ``modelName``). Empty: usable."""
    p = Path(path)
    where = str(p)
    if not p.is_file():
        return [f"{where}: no such file"]
    try:
        zf = zipfile.ZipFile(p)
    except (zipfile.BadZipFile, OSError, ValueError, EOFError) as exc:
        return [f"{where}: not an FMU (not a zip archive: {exc})"]
    with zf:
        problems = member_problems(zf, where)
        if problems:
            return problems
        names = set(zf.namelist())
        if "modelDescription.xml" not in names:
            return [f"{where}: no modelDescription.xml"]
        info = zf.getinfo("modelDescription.xml")
        if info.file_size > MAX_XML_BYTES:
            return [f"{where}: modelDescription.xml has {info.file_size} bytes (at most {MAX_XML_BYTES})"]
        try:
            text = zf.read("modelDescription.xml")
        except (zipfile.BadZipFile, OSError, ValueError, EOFError, RuntimeError) as exc:
            return [f"{where}: modelDescription.xml unreadable ({exc})"]
        root, problems = _parse_description(text, where)
        if root is None:
            return problems
        problems, guid, ident = description_problems(root, where, model)
        if ident is None or problems:
            return problems
        binary = _platform_binary(ident)
        if binary not in names:
            return [f"{where}: no binary for this platform ({binary})"]
        try:
            data = zf.read(binary)
        except (zipfile.BadZipFile, OSError, ValueError, EOFError, RuntimeError) as exc:
            return [f"{where}: {binary} unreadable ({exc})"]
        bare = guid.strip("{}").encode()
        if _GUID_RE.search(data) and bare.lower() not in data.lower():
            problems.append(f"{where}: guid {guid!r} of the model description is not the one its binary was built "
                            f"with ({binary}): a description from another build")
    return problems


__all__ = ["fmu_archive_problems", "member_problems", "MAX_XML_BYTES", "MAX_MEMBERS", "MAX_UNPACKED_BYTES"]
