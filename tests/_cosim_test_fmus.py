"""Small pythonfmu FMUs for testing the master (not part of the product).

- ``MTInertia``: a rigid inertia on an inertia-side flange ``flange`` (input tau; outputs phi, w) with
  viscous damping to ground and a constant source torque. Integrated with the implicit midpoint rule,
  whose discrete energy balance is exact: the work of the held input torque is tau·(phi_end − phi_start).
- ``MTSpring``: a spring–damper between two spring-side flanges ``flange_a``, ``flange_b`` (inputs phi,
  w; outputs tau); the deflection is extrapolated with the held input speeds over the step.
- ``MTInertiaRpm``: MTInertia whose ``flange_w`` is declared in rpm (for the unit-mismatch test).

Each can fail on purpose: ``fail_at_s >= 0`` makes do_step log an error and return False (fail_mode 1)
or raise (fail_mode 2) once the time reaches it.
"""
from __future__ import annotations

import re
import shutil
import zipfile
from pathlib import Path
from xml.etree import ElementTree as ET

INERTIA_SRC = '''
from pythonfmu import Fmi2Causality, Fmi2Variability, Fmi2Slave, Real, Integer, Fmi2Initial
from pythonfmu.enums import Fmi2Status


class {cls}(Fmi2Slave):
    description = "test inertia"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.J = 0.01
        self.d = 0.02
        self.tau_src = 0.0
        self.phi0 = 0.0
        self.w0 = 0.0
        self.n_sub = 4
        self.fail_at_s = -1.0
        self.fail_mode = 1
        self.flange_tau = 0.0
        self.flange_phi = 0.0
        self.flange_w = 0.0
        self.energy_stored = 0.0
        self.energy_dissipated = 0.0
        self.energy_supplied = 0.0
        P = Fmi2Causality.parameter
        for n in ("J", "d", "tau_src", "phi0", "w0", "fail_at_s"):
            self.register_variable(Real(n, causality=P, variability=Fmi2Variability.tunable))
        for n in ("n_sub", "fail_mode"):
            self.register_variable(Integer(n, causality=P, variability=Fmi2Variability.fixed))
        self.register_variable(Real("flange_tau", causality=Fmi2Causality.input))
        for n in ("flange_phi", "flange_w", "energy_stored", "energy_dissipated", "energy_supplied"):
            self.register_variable(Real(n, causality=Fmi2Causality.output, initial=Fmi2Initial.exact))

    def enter_initialization_mode(self):
        self.flange_phi = self.phi0
        self.flange_w = self.w0
        self.energy_stored = 0.5 * self.J * self.w0 ** 2

    exit_initialization_mode = enter_initialization_mode

    def do_step(self, t, dt):
        if self.fail_at_s >= 0.0 and t >= self.fail_at_s:
            if self.fail_mode == 2:
                raise RuntimeError("deliberate exception at t = %.6f" % t)
            self.log("deliberate failure of %s at t = %.6f s" % (self.instance_name, t), Fmi2Status.error)
            return False
        h = dt / self.n_sub
        w = self.flange_w
        phi = self.flange_phi
        tau = self.flange_tau + self.tau_src
        a = h / self.J
        for _ in range(self.n_sub):
            # implicit midpoint: w1 = w + a (tau - d (w + w1)/2)
            w1 = (w * (1.0 - 0.5 * a * self.d) + a * tau) / (1.0 + 0.5 * a * self.d)
            wm = 0.5 * (w + w1)
            phi += h * wm
            self.energy_dissipated += h * self.d * wm * wm
            self.energy_supplied += h * self.tau_src * wm
            w = w1
        self.flange_w = w
        self.flange_phi = phi
        self.energy_stored = 0.5 * self.J * w * w
        return True
'''

SPRING_SRC = '''
from pythonfmu import Fmi2Causality, Fmi2Variability, Fmi2Slave, Real, Integer, Fmi2Initial


class {cls}(Fmi2Slave):
    description = "test spring-damper"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.k = 50.0
        self.c = 0.05
        self.flange_a_phi = 0.0
        self.flange_a_w = 0.0
        self.flange_b_phi = 0.0
        self.flange_b_w = 0.0
        self.flange_a_tau = 0.0
        self.flange_b_tau = 0.0
        self.energy_stored = 0.0
        self.energy_dissipated = 0.0
        self.energy_supplied = 0.0
        P = Fmi2Causality.parameter
        for n in ("k", "c"):
            self.register_variable(Real(n, causality=P, variability=Fmi2Variability.tunable))
        for n in ("flange_a_phi", "flange_a_w", "flange_b_phi", "flange_b_w"):
            self.register_variable(Real(n, causality=Fmi2Causality.input))
        for n in ("flange_a_tau", "flange_b_tau", "energy_stored", "energy_dissipated", "energy_supplied"):
            self.register_variable(Real(n, causality=Fmi2Causality.output, initial=Fmi2Initial.exact))

    def _out(self, dphi, dw):
        tau = -self.k * dphi - self.c * dw
        self.flange_a_tau = tau
        self.flange_b_tau = -tau
        self.energy_stored = 0.5 * self.k * dphi * dphi

    def exit_initialization_mode(self):
        self._out(self.flange_a_phi - self.flange_b_phi, self.flange_a_w - self.flange_b_w)

    def do_step(self, t, dt):
        dw = self.flange_a_w - self.flange_b_w
        dphi = self.flange_a_phi - self.flange_b_phi + dw * dt
        self.energy_dissipated += self.c * dw * dw * dt
        self._out(dphi, dw)
        return True
'''

UNITS = {"phi": "rad", "w": "rad/s", "tau": "N.m", "energy": "J", "J": "kg.m2", "k": "N.m/rad",
         "c": "N.m.s/rad", "d": "N.m.s/rad", "tau_src": "N.m", "phi0": "rad", "w0": "rad/s", "fail_at_s": "s"}


def _unit_for(name: str, overrides: dict) -> str | None:
    if name in overrides:
        return overrides[name]
    if name.startswith("energy_"):
        return "J"
    m = re.search(r"_(phi|w|tau)$", name)
    if m:
        return UNITS[m.group(1)]
    return UNITS.get(name)


def add_units(fmu: Path, overrides: dict | None = None) -> None:
    """Post-process modelDescription.xml: unit attributes on Real variables + UnitDefinitions."""
    overrides = overrides or {}
    tmp = fmu.with_suffix(".tmp")
    with zipfile.ZipFile(fmu) as zin, zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as zout:
        for item in zin.infolist():
            data = zin.read(item.filename)
            if item.filename == "modelDescription.xml":
                root = ET.fromstring(data)
                used = set()
                for sv in root.iter("ScalarVariable"):
                    real = sv.find("Real")
                    if real is None:
                        continue
                    u = _unit_for(sv.get("name"), overrides)
                    if u:
                        real.set("unit", u)
                        used.add(u)
                ud = ET.Element("UnitDefinitions")
                for u in sorted(used):
                    ET.SubElement(ud, "Unit", name=u)
                children = list(root)
                idx = next(i for i, c in enumerate(children) if c.tag in ("LogCategories", "DefaultExperiment",
                                                                            "ModelVariables"))
                root.insert(idx, ud)
                data = ET.tostring(root, encoding="UTF-8", xml_declaration=True)
            zout.writestr(item, data)
    shutil.move(tmp, fmu)


def build_test_fmus(out_dir: Path) -> dict[str, Path]:
    from pythonfmu.builder import FmuBuilder

    out_dir = Path(out_dir)
    src_dir = out_dir / "src"
    src_dir.mkdir(parents=True, exist_ok=True)
    specs = {
        "MTInertia": (INERTIA_SRC, {}),
        "MTSpring": (SPRING_SRC, {}),
        "MTInertiaRpm": (INERTIA_SRC, {"flange_w": "rpm"}),
    }
    paths = {}
    for cls, (src, unit_over) in specs.items():
        script = src_dir / f"{cls}.py"
        script.write_text(src.replace("{cls}", cls))
        fmu = FmuBuilder.build_FMU(script, dest=out_dir, needsExecutionTool="false")
        add_units(Path(fmu), unit_over)
        paths[cls] = Path(fmu)
    return paths


def toy_spec():
    """Motor inertia -> spring -> load inertia of the test FMUs above, standing in for the drivetrain (sensors
    mapped)."""
    from drivetrain.system import ComponentSpec, Connection, SystemSpec

    return SystemSpec(
        components=[ComponentSpec("motor", "MTInertia", {"J": 0.01, "d": 0.002, "tau_src": 1.0}),
                    ComponentSpec("shaft", "MTSpring", {"k": 300.0, "c": 0.05}),
                    ComponentSpec("load", "MTInertia", {"J": 0.02, "d": 0.01})],
        connections=[Connection("shaft.flange_a", "motor.flange"), Connection("shaft.flange_b", "load.flange")],
        comm_step=1.0 / 12000.0,
        metadata={"sensors": {"drive_shaft_torque": "shaft.flange_b_tau", "propeller_shaft_torque": "shaft.flange_b_tau",
                              "enc1": "motor.flange_phi", "enc5": "load.flange_phi"}})
