"""Shared by the native FMU tests: an FMU instance through fmpy whose log messages land in
``s.log_lines()`` (the master's logger routes: fmpy's one logger proxy is shared by the whole process,
and a test before may have pointed it elsewhere, so printing through fmpy's default callbacks is not
reliable; see drivetrain.cosim.slaves), and parameters set by name with their types."""
import fmpy
from fmpy.fmi2 import FMU2Slave

KEEP = []     # instances and their callbacks stay alive until exit (pythonfmu instances: docs/FMU.md)


def open_instance(path, params=None, name="x", unzip_dir=None):
    """An instance of the FMU at ``path`` (extracted to ``unzip_dir``, else a fresh directory) and its
    variables by name; ``params`` set before initialization."""
    from drivetrain.cosim.slaves import FmiCallbacks

    md = fmpy.read_model_description(str(path))
    s = FMU2Slave(guid=md.guid, unzipDirectory=unzip_dir or fmpy.extract(str(path)),
                  modelIdentifier=md.coSimulation.modelIdentifier, instanceName=name)
    cbs = FmiCallbacks()
    s.instantiate(callbacks=cbs.struct, loggingOn=True)
    s.log_lines = lambda: drain(cbs, name)
    KEEP.append((s, cbs))
    vr = {v.name: v for v in md.modelVariables}
    set_values(s, vr, params or {})
    return s, vr


def drain(cbs, name) -> str:
    """The instance's log messages since the last call, one per line."""
    log = cbs.logs.get(name)
    if log is None:
        return ""
    text = "\n".join(log.lines)
    log.lines.clear()
    return text


def set_values(s, vr, params):
    """Set variables by name, each with its declared type."""
    for k, v in params.items():
        t, ref = vr[k].type, [vr[k].valueReference]
        if t == "Real":
            s.setReal(ref, [float(v)])
        elif t == "Integer":
            s.setInteger(ref, [int(v)])
        elif t == "Boolean":
            s.setBoolean(ref, [bool(v)])
        else:
            s.setString(ref, [str(v)])


def get_values(s, vr, names):
    """Numeric variables by name (Real, Integer counters, Boolean switches) as floats, each read with its
    declared type's get call."""
    out = []
    for n in names:
        t, ref = vr[n].type, [vr[n].valueReference]
        get = {"Real": s.getReal, "Integer": s.getInteger, "Boolean": s.getBoolean}[t]
        out.append(float(get(ref)[0]))
    return out


def case_records(stdout: str) -> tuple[dict, str | None]:
    """A case subprocess's JSON lines: ({case name: record}, the last case started). Non-JSON lines (a
    library printing) are skipped; a case started without a record is the one that crashed."""
    import json

    done, started = {}, None
    for ln in stdout.splitlines():
        try:
            rec = json.loads(ln)
        except ValueError:
            continue
        if "start" in rec:
            started = rec["start"]
        elif "case" in rec:
            done[rec["case"]] = rec
    return done, started
