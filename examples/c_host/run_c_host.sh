#!/usr/bin/env bash
# Run the GearContact FMU from a non-Python FMI host (a small C program): extract the FMU, compile the
# host against fmpy's FMI 2.0 headers, then run it with libpython preloaded and PYTHONPATH set to the
# site-packages that hold numpy/numba/scipy (and the project, unless the bundled copy is wanted).
#
#   examples/c_host/run_c_host.sh [fmus/GearContact.fmu] [nan_at_step]
#   examples/c_host/run_c_host.sh --native fmus/native/GearContact.fmu [nan_at_step]
#
# Uses the project venv's interpreter to locate libpython and site-packages (and the FMI headers).
# --native: the FMU is the Python-free GearContact (drivetrain build-native-gear): no LD_PRELOAD,
# PYTHONHOME or PYTHONPATH, and the host runs with an empty environment but PATH.
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
root="$(cd "$here/../.." && pwd)"
native=0
if [ "${1:-}" = "--native" ]; then
    native=1
    shift
fi
fmu="${1:-$root/fmus/GearContact.fmu}"
nan_at="${2:--1}"
py="${PYTHON:-$root/.venv/bin/python}"

work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
unzip -q "$fmu" -d "$work/fmu"

fmi_headers="$("$py" -c 'import fmpy, os; print(os.path.join(os.path.dirname(fmpy.__file__), "c-code"))')"
gcc -O1 -std=c99 -D_GNU_SOURCE -I"$fmi_headers" -o "$work/host" "$here/gearcontact_host.c" -ldl -lm

# value references from the model description
read -r vrs < <("$py" - "$work/fmu/modelDescription.xml" <<'EOF'
import sys, xml.etree.ElementTree as ET
vr = {v.get("name"): v.get("valueReference") for v in ET.parse(sys.argv[1]).getroot().iter("ScalarVariable")}
print(" ".join(vr[n] for n in ("flange_a_phi", "flange_a_w", "flange_b_phi", "flange_b_w", "flange_a_tau", "flange_b_tau")))
EOF
)

if [ "$native" = 1 ]; then
    rc=0
    # shellcheck disable=SC2086
    env -i PATH=/usr/bin:/bin "$work/host" "$work/fmu" $vrs "$nan_at" || rc=$?
    exit "$rc"
fi

# what a non-Python tool needs: the interpreter library and the packages the FMU imports
libpython="$("$py" -c 'import sysconfig, os; print(os.path.join(sysconfig.get_config_var("LIBDIR"), sysconfig.get_config_var("INSTSONAME")))')"
site="$("$py" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')"
pyhome="$("$py" -c 'import sys; print(sys.base_prefix)')"
echo "LD_PRELOAD=$libpython"
echo "PYTHONHOME=$pyhome"
echo "PYTHONPATH=$site"
# shellcheck disable=SC2086
LD_PRELOAD="$libpython" PYTHONHOME="$pyhome" PYTHONPATH="$site" "$work/host" "$work/fmu" $vrs "$nan_at"
