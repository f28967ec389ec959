"""The FMI 2.0 headers every C build of the project compiles (native FMUs, the pythonfmu FMUs' FMI wrapper) and
ships in ``sources/``: fmpy's copy, with ``FMI2_FUNCTION_PREFIX`` honoured (:func:`fmi2_functions_header`)."""
from __future__ import annotations

import shutil
from pathlib import Path

FMI_HEADERS = ("fmi2Functions.h", "fmi2FunctionTypes.h", "fmi2TypesPlatform.h")


def fmi_header_dir() -> Path:
    """fmpy's copy of the FMI 2.0 headers."""
    import fmpy

    return Path(fmpy.__file__).resolve().parent / "c-code"


#: fmpy's fmi2Functions.h names the functions without a prefix whatever FMI2_FUNCTION_PREFIX says; the standard
#: header's rule (FMI 2.0.x) is put back, so that a source FMU compiled with -DFMI2_FUNCTION_PREFIX=Model_ exports
#: Model_fmi2Instantiate ... and several can be linked into one binary
_NO_PREFIX = "#define fmi2FullName(name) name\n"
_PREFIX_RULE = ("#ifdef FMI2_FUNCTION_PREFIX\n"
                "#define fmi2Paste(a,b)     a ## b\n"
                "#define fmi2PasteB(a,b)    fmi2Paste(a,b)\n"
                "#define fmi2FullName(name) fmi2PasteB(FMI2_FUNCTION_PREFIX, name)\n"
                "#else\n"
                "#define fmi2FullName(name) name\n"
                "#endif\n")


def fmi2_functions_header() -> str:
    """fmi2Functions.h as shipped in sources/: fmpy's copy with FMI2_FUNCTION_PREFIX honoured."""
    text = (fmi_header_dir() / "fmi2Functions.h").read_text()
    if "FMI2_FUNCTION_PREFIX, name" in text:
        return text
    if _NO_PREFIX not in text:
        raise ValueError("fmpy's fmi2Functions.h has no fmi2FullName definition to make prefix-aware")
    return text.replace(_NO_PREFIX, _PREFIX_RULE, 1)


def copy_fmi_headers(dest: Path) -> None:
    """The FMI 2.0 headers into ``dest`` (fmi2Functions.h prefix-aware)."""
    for name in FMI_HEADERS:
        if name == "fmi2Functions.h":
            (Path(dest) / name).write_text(fmi2_functions_header())
        else:
            shutil.copy2(fmi_header_dir() / name, Path(dest) / name)
