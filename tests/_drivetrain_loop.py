"""A minimal in-process Jacobi co-simulation loop over the component classes (no FMI, no master):
the same exchange as the master (outputs at t_n -> inputs, every component steps [t_n, t_n + H]).
Used by the drivetrain tests (ring-down, time-domain mean torques, stability)."""
from __future__ import annotations

import math

import numpy as np

from drivetrain.components import ComponentError, make_component
from drivetrain.system import SystemSpec


class _Gear:
    """The gear stage (gearcontact_fmu.stage) behind the same small interface."""

    def __init__(self, params: dict):
        from gearcontact_fmu.stage import StageParams, make_stage

        p = dict(params)
        sp = StageParams(J_pinion=p["J_pinion"], J_wheel=p["J_wheel"], k_a=p["k_a"], d_a=p["d_a"], k_b=p["k_b"],
                         d_b=p["d_b"], max_substep=p.get("max_substep", 1e-5))
        fid = p.get("fidelity", "ideal")
        kw = {}
        if fid == "analytic":
            kw = dict(damping_ratio=p.get("mesh_damping_ratio", 0.05), mu=p.get("mu", 0.002))
        self.stage = make_stage(fid, stage_params=sp, **kw)
        self.inputs = dict(flange_a_phi=0.0, flange_a_w=0.0, flange_b_phi=0.0, flange_b_w=0.0)

    def init(self):
        i = self.inputs
        self.stage.initialize(0.0, i["flange_a_phi"], i["flange_a_w"], i["flange_b_phi"], i["flange_b_w"])

    def step(self, t, H):
        i = self.inputs
        self.stage.step(t, H, i["flange_a_phi"], i["flange_a_w"], i["flange_b_phi"], i["flange_b_w"])

    def outputs(self):
        st = self.stage
        return {"flange_a_tau": st.tau_a, "flange_b_tau": st.tau_b, "flange_a_tau_mean": st.tau_a_mean,
                "flange_b_tau_mean": st.tau_b_mean, "flange_b_tau_mean_": st.tau_b_mean,
                "pinion_phi": st.theta_pinion, "wheel_phi": st.theta_wheel,
                "pinion_w": st.omega_pinion, "wheel_w": st.omega_wheel,
                "energy_stored": st.energy_stored, "energy_dissipated": st.energy_dissipated,
                "energy_supplied": 0.0}


class Loop:
    def __init__(self, spec: SystemSpec, overrides: dict | None = None):
        self.spec = spec
        self.H = spec.comm_step
        self.comps = {}
        self.inputs = {}
        for c in spec.components:
            params = dict(c.parameters)
            params.update((overrides or {}).get(c.name, {}))
            if c.model == "GearContact":
                self.comps[c.name] = _Gear(params)
            else:
                self.comps[c.name] = make_component(c.model, params)
            self.inputs[c.name] = dict(c.inputs)
        self.t = 0.0
        # initial exchange (inertia-side outputs are defined by the initial state)
        self.out = {n: self._outputs(n, initial=True) for n in self.comps}
        self._exchange()
        if "gear" in self.comps and isinstance(self.comps["gear"], _Gear):
            self.comps["gear"].init()
        self.out = {n: self._outputs(n, initial=True) for n in self.comps}

    def _outputs(self, name, initial=False):
        c = self.comps[name]
        o = c.outputs()
        if initial and not isinstance(c, _Gear):
            # spring ports: instantaneous spring torque against the current flange inputs
            for p in c.line.ports:
                if p.kind == 1:
                    q = c.line.port_index[p.name]
                    o[f"{p.name}_tau"] = c.line.spring_torque(p.name, c.line.p_u0[q], c.line.p_u1[q])
        return o

    def _exchange(self):
        vals = {}
        for conn in self.spec.connections:
            sc, sp = conn.spring.split(".", 1)
            ic, ip = conn.inertia.split(".", 1)
            vals.setdefault(sc, {})[f"{sp}_phi"] = self.out[ic][f"{ip}_phi"]
            vals.setdefault(sc, {})[f"{sp}_w"] = self.out[ic][f"{ip}_w"]
            vals.setdefault(ic, {})[f"{ip}_tau"] = self.out[sc].get(f"{sp}_tau", 0.0)
        for name, v in vals.items():
            c = self.comps[name]
            if isinstance(c, _Gear):
                c.inputs.update(v)
                continue
            m = c.model
            if m == "FlexibleShaft":
                c.set_inputs(v["flange_a_tau"], v["flange_b_phi"], v["flange_b_w"])
            elif m == "UpperTransmission":
                c.set_inputs(v["flange_a_tau"], v["flange_b_tau"])
            elif m == "MotorLoad":
                extra = {}
                for key in ("speed_ref_rpm", "load_torque"):
                    val = self.inputs[name].get(key)
                    if isinstance(val, (list, tuple)):
                        arr = np.asarray(val, dtype=float)
                        val = float(np.interp(self.t, arr[:, 0], arr[:, 1]))
                    if val is not None:
                        extra[key] = val
                c.set_inputs(v["drive_phi"], v["drive_w"], v["load_tau"], **extra)

    def step(self):
        self._exchange()
        for c in self.comps.values():
            c.step(self.t, self.H)
        self.t += self.H
        self.out = {n: self.comps[n].outputs() for n in self.comps}

    def run(self, duration, record=(), every=1):
        n = int(round(duration / self.H))
        rec = {r: np.empty(n // every + 1) for r in record}
        ts = np.empty(n // every + 1)
        k = 0
        for r in record:
            c, v = r.split(".", 1)
            rec[r][0] = self.out[c][v]
        ts[0] = self.t
        for i in range(1, n + 1):
            self.step()
            if i % every == 0:
                k += 1
                ts[k] = self.t
                for r in record:
                    c, v = r.split(".", 1)
                    rec[r][k] = self.out[c][v]
        return ts[: k + 1], {r: a[: k + 1] for r, a in rec.items()}
