"""The C headers of the FMI runtime that every C build of the project compiles (native FMUs, the pythonfmu FMUs'
FMI wrapper) and ships in ``sources/``, kept in ``fmu_runtime/native`` (where every FMU's runtime lives):

- the Modelica Association's FMI 2.0.5 headers (github.com/modelica/fmi-standard, tag v2.0.5, ``headers/``,
  2-clause BSD): :data:`FMI_HEADERS`;
- ``fmi2_state.h``: the FMI 2.0 co-simulation state machine's rules and messages, written once for the native
  shell and the pythonfmu wrapper (:data:`STATE_HEADER`);
- ``fmi2_shell.h``: the native FMUs' shell (:data:`SHELL_HEADER`; the wrapper does not include it).

fmpy's copy of the standard headers, used before issue 30, has ``fmi2FullName`` changed to ignore
``FMI2_FUNCTION_PREFIX``: two source FMUs compiled into one binary then clashed on every fmi2 symbol. With the
standard headers, ``-DFMI2_FUNCTION_PREFIX=<model>_`` names them apart."""
from __future__ import annotations

import shutil
from pathlib import Path

import fmu_runtime

FMI_HEADERS = ("fmi2Functions.h", "fmi2FunctionTypes.h", "fmi2TypesPlatform.h")
#: the state machine's rules and messages (included by fmi2_shell.h and by the pythonfmu wrapper)
STATE_HEADER = "fmi2_state.h"
#: the native FMUs' FMI shell (includes STATE_HEADER)
SHELL_HEADER = "fmi2_shell.h"
#: what every C build compiles besides its own sources: the standard headers and the state machine
COMMON_HEADERS = (*FMI_HEADERS, STATE_HEADER)


def fmi_header_dir() -> Path:
    """Where the FMI runtime's C headers are kept (``fmu_runtime/native``)."""
    return Path(fmu_runtime.__file__).resolve().parent / "native"


def copy_fmi_headers(dest: Path) -> None:
    """The FMI 2.0 headers and the state machine's (:data:`COMMON_HEADERS`) into ``dest``."""
    for name in COMMON_HEADERS:
        shutil.copy2(fmi_header_dir() / name, Path(dest) / name)
