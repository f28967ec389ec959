"""The FMI 2.0 headers every C build of the project compiles (native FMUs, the pythonfmu FMUs' FMI wrapper) and
ships in ``sources/``: the Modelica Association's FMI 2.0.5 headers (github.com/modelica/fmi-standard, tag v2.0.5,
``headers/``, 2-clause BSD), kept in ``gearcontact_fmu/native``.

fmpy's copy, used before issue 30, has ``fmi2FullName`` changed to ignore ``FMI2_FUNCTION_PREFIX``: two source
FMUs compiled into one binary then clashed on every fmi2 symbol. With the standard headers,
``-DFMI2_FUNCTION_PREFIX=<model>_`` names them apart."""
from __future__ import annotations

import shutil
from pathlib import Path

import gearcontact_fmu

FMI_HEADERS = ("fmi2Functions.h", "fmi2FunctionTypes.h", "fmi2TypesPlatform.h")


def fmi_header_dir() -> Path:
    """Where the standard FMI 2.0.5 headers are kept."""
    return Path(gearcontact_fmu.__file__).resolve().parent / "native"


def copy_fmi_headers(dest: Path) -> None:
    """The FMI 2.0 headers into ``dest``."""
    for name in FMI_HEADERS:
        shutil.copy2(fmi_header_dir() / name, Path(dest) / name)
