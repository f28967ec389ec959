"""doStep cost of the native GearContact against the pythonfmu GearContact, through fmpy, in one run.

Both FMUs get the example scene's gear parameters (table, 48 x 48 map, max_substep 5 us, ros2) and the
same input trajectory at H = 1/12000 s: 1500 rpm, the flanges twisted by 6e-3 rad (pinion-referred;
about the scene's load) with a 70 Hz swing of 3e-3 rad, so that contacts change and sub-steps are
halved as in a run. Per step, as our master does (raw ctypes calls on preallocated buffers): one setReal
of the four flange inputs, doStep, one getReal of the two coupling torques; the doStep call is also
timed alone. The two FMUs run alternately in rounds (best round of each: the
least disturbed by other jobs on a shared machine); the first steps of each (JIT warm-up) are excluded.
Prints us per doStep and per whole step of each, the ratios and the largest torque difference; and, for
where the time goes, the pythonfmu FMU's model in this process without FMI (the numba stage kernel
alone, and GearStage.step around it).

The doStep figures include what calling any C function through ctypes costs this Python host (argument
conversion, the foreign call; about 2 us here, the same for both FMUs). It is measured in the same
loop as "call floor": a ctypes call with doStep's signature to a C function that returns at once (the
native FMU's fmi2CancelStep; the extra arguments are ignored under the C calling convention), timed
like doStep. "net" is doStep minus that floor: what the FMU itself costs, i.e. what a C host pays.

    python benchmarks/bench_native_gear.py [--steps 6000] [--rounds 5] [--max-substep 1e-5]   # ~30 s
    python benchmarks/bench_native_gear.py --baseline-c OLD.c    # also a native build from another C source

--baseline-c compiles the same FMU (map, header) from another version of gearcontact_native.c and runs it
in the same rounds as "baseline": old and new builds side by side, as the machine's load varies.
"""
import argparse
import ctypes
import functools
import math
import tempfile
import subprocess
import time
import zipfile
from pathlib import Path

import fmpy
import numpy as np
from fmpy.fmi2 import FMU2Slave

from drivetrain.fmu_build.build import build_all, slave_class
from drivetrain.fmu_build.native_gear import C_SOURCE, build_native_gear, compile_command
from drivetrain.run.assemble import gear_parameters
from drivetrain.scene.load import load_scene
from gearcontact_fmu.params import GEAR_MODEL

ROOT = Path(__file__).resolve().parents[1]
ap = argparse.ArgumentParser()
ap.add_argument("--steps", type=int, default=6000)
ap.add_argument("--rounds", type=int, default=5)
ap.add_argument("--max-substep", type=float, default=None, help="override the scene's numerics.max_substep_s [s]")
ap.add_argument("--baseline-c", type=Path, action="append", default=[],
                help="also run a native build compiled from this C source (repeatable)")
args = ap.parse_args()

H = 1.0 / 12000.0
WARMUP = 200
tmp = Path(tempfile.mkdtemp(prefix="bench_native_"))
gear = gear_parameters(load_scene(ROOT / "scenarios" / "example.toml"))
if args.max_substep:
    gear["max_substep"] = args.max_substep
fmus = {"native": build_native_gear(gear, tmp / "native" / "GearContact.fmu"),
        "pythonfmu": build_all(tmp / "py", only=["GearContact"])[0]}


def rebuild_from(fmu: Path, c_source: Path, out: Path) -> Path:
    """fmu with its binary compiled from c_source instead (same map, header and model description)."""
    d = out.with_suffix("")
    with zipfile.ZipFile(fmu) as z:
        z.extractall(d)
    (d / "sources" / C_SOURCE).write_bytes(c_source.read_bytes())
    subprocess.run(compile_command(d / "sources", d / "binaries" / "linux64" / f"{GEAR_MODEL}.so"), check=True)
    with zipfile.ZipFile(out, "w") as z:
        for f in sorted(d.rglob("*")):
            if f.is_file():
                z.write(f, f.relative_to(d).as_posix())
    return out


baselines = {f"baseline{i or ''}": src for i, src in enumerate(args.baseline_c)}
for name, src in baselines.items():
    fmus[name] = rebuild_from(fmus["native"], src, tmp / f"{name}.fmu")
# the call floor's target: a C function that returns at once (the native FMU's fmi2CancelStep)
_floor_lib = ctypes.CDLL(str(Path(fmpy.extract(str(fmus["native"]))) / "binaries" / "linux64" / "GearContact.so"))
floor_addr = _floor_lib.fmi2CancelStep

n_total = WARMUP + args.steps
w = 50.0 * math.pi
t = np.arange(n_total) * H
delta = np.minimum(t / 0.02, 1.0) * (6e-3 + 3e-3 * np.sin(2 * math.pi * 70.0 * t))
U = np.column_stack([w * t, np.full_like(t, w), (w * t - delta) / 4.0, np.full_like(t, w / 4.0)])
keep = []


def run(path):
    """us per step of the doStep call alone and of the whole exchange (setReal, doStep, getReal), with
    the raw FMI calls on preallocated buffers that our master makes (drivetrain.cosim.slaves.FmiSlave)."""
    md = fmpy.read_model_description(str(path))
    s = FMU2Slave(guid=md.guid, unzipDirectory=fmpy.extract(str(path)), modelIdentifier="GearContact",
                  instanceName="gear")
    s.instantiate()
    keep.append(s)                      # pythonfmu instances stay loaded until exit (docs/FMU.md)
    vr = {v.name: v for v in md.modelVariables}
    for k, v in gear.items():
        ref = [vr[k].valueReference]
        {"Real": s.setReal, "Integer": s.setInteger, "Boolean": s.setBoolean, "String": s.setString}[vr[k].type](
            ref, [v if vr[k].type != "Real" else float(v)])
    names_in = ("flange_a_phi", "flange_a_w", "flange_b_phi", "flange_b_w")
    s.setupExperiment(startTime=0.0)
    s.enterInitializationMode()
    s.setReal([vr[k].valueReference for k in names_in], U[0].tolist())
    s.exitInitializationMode()
    u = np.zeros(4)
    y = np.zeros(2)
    vin = (ctypes.c_uint * 4)(*[vr[k].valueReference for k in names_in])
    vout = (ctypes.c_uint * 2)(vr["flange_a_tau"].valueReference, vr["flange_b_tau"].valueReference)
    dp = ctypes.POINTER(ctypes.c_double)
    f = s._functions
    addr = lambda fn: ctypes.cast(fn, ctypes.c_void_p).value  # noqa: E731
    raw = ctypes.CFUNCTYPE(ctypes.c_int)
    c = ctypes.c_void_p(s.component)
    set_fn = functools.partial(raw(addr(f["fmi2SetReal"])), c, vin, ctypes.c_size_t(4), ctypes.cast(u.ctypes.data, dp))
    get_fn = functools.partial(raw(addr(f["fmi2GetReal"])), c, vout, ctypes.c_size_t(2), ctypes.cast(y.ctypes.data, dp))
    step_fn = functools.partial(ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p, ctypes.c_double, ctypes.c_double,
                                                 ctypes.c_int)(addr(f["fmi2DoStep"])), c)
    floor_fn = functools.partial(ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p, ctypes.c_double, ctypes.c_double,
                                                  ctypes.c_int)(addr(floor_addr)), c)
    out = np.empty((n_total, 2))
    t_step = t_floor = 0.0
    clock = time.perf_counter
    t0 = None
    for k in range(n_total):
        if k == WARMUP:
            t_step = t_floor = 0.0
            t0 = clock()
        u[:] = U[k]
        set_fn()
        ts = clock()
        status = step_fn(k * H, H, 1)
        t_step += clock() - ts
        if status != 0:
            raise RuntimeError(f"{path}: doStep at step {k} returned {status}")
        get_fn()
        out[k] = y
        ts = clock()
        floor_fn(k * H, H, 1)
        t_floor += clock() - ts
    total = clock() - t0 - t_floor
    return t_step / args.steps * 1e6, total / args.steps * 1e6, t_floor / args.steps * 1e6, out


def run_kernel():
    """The pythonfmu FMU's model without FMI: the numba stage kernel alone, and GearStage.step (the
    kernel plus the Python around it: energy balance, coupling correction), in this process."""
    cls = slave_class(ROOT / "src" / "gearcontact_fmu" / "slaves" / f"{GEAR_MODEL}.py")
    slave = cls(instance_name="bench", resources=tempfile.gettempdir())
    for k, v in gear.items():
        setattr(slave, k, v)
    slave._build()
    st = slave._stage
    st.initialize(0.0, *U[0])
    clock = time.perf_counter
    t_step = 0.0
    for k in range(n_total):
        ts = clock()
        st.step(k * H, H, *U[k])
        if k >= WARMUP:
            t_step += clock() - ts
    st.initialize(0.0, *U[0])
    n_sub = st.n_substeps(H)
    t_kernel = 0.0
    for k in range(n_total):
        st.u[:] = U[k]
        ts = clock()
        st._run(st.model.data, st._mode, st._scheme, st.x, st._par, st.u, H, n_sub, st.out, st._res)
        if k >= WARMUP:
            t_kernel += clock() - ts
    return t_kernel / args.steps * 1e6, t_step / args.steps * 1e6


best = {k: [math.inf, math.inf] for k in fmus}
best_kernel = [math.inf, math.inf]
best_floor = math.inf
outs = {}
for _ in range(args.rounds):
    for name, path in fmus.items():
        us_step, us_total, us_floor, outs[name] = run(path)
        best[name] = [min(best[name][0], us_step), min(best[name][1], us_total)]
        best_floor = min(best_floor, us_floor)
    best_kernel = [min(a, b) for a, b in zip(best_kernel, run_kernel())]
diff = np.max(np.abs(outs["native"] - outs["pythonfmu"])) / np.max(np.abs(outs["pythonfmu"]))
print(f"steps {args.steps} (+{WARMUP} warm-up) at H = 1/12000 s, max_substep {gear['max_substep']:g} s, "
      f"best of {args.rounds} rounds")
print("| FMU | us per doStep | us per step (setReal + doStep + getReal, raw ctypes calls) |")
print("|---|---|---|")
for name in fmus:
    print(f"| {name} | {best[name][0]:.1f} | {best[name][1]:.1f} |")
print(f"| (pythonfmu's model in-process: numba stage kernel / GearStage.step) | {best_kernel[0]:.1f} | "
      f"{best_kernel[1]:.1f} |")
print(f"| (call floor: a ctypes call of doStep's signature that returns at once) | {best_floor:.1f} | |")
net = {k: best[k][0] - best_floor for k in fmus}
print(f"net doStep (minus the call floor): native {net['native']:.1f} us, pythonfmu {net['pythonfmu']:.1f} us")
print(f"ratio pythonfmu / native: doStep {best['pythonfmu'][0] / best['native'][0]:.1f}x, "
      f"whole step {best['pythonfmu'][1] / best['native'][1]:.1f}x, net doStep {net['pythonfmu'] / net['native']:.1f}x")
print(f"largest torque difference, relative to the largest torque: {diff:.3g}")
for b, src in baselines.items():
    print(f"{b} ({src}): doStep {best[b][0]:.1f} us, net {net[b]:.1f} us; "
          f"ratio pythonfmu / {b}: doStep {best['pythonfmu'][0] / best[b][0]:.1f}x, "
          f"net doStep {net['pythonfmu'] / net[b]:.1f}x; {b} / native doStep {best[b][0] / best['native'][0]:.2f}x")
