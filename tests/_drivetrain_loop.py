"""A minimal in-process Jacobi co-simulation loop over the component classes (no FMI, no master):
the same exchange as the master (outputs at t_n -> inputs, every component steps [t_n, t_n + H]).
Used by the drivetrain tests (ring-down, time-domain mean torques, stability)."""
from __future__ import annotations

import math

import numpy as np

from drivetrain.components import ComponentError, make_component
from drivetrain.system import SPRING, SystemSpec


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
            kw = dict(damping_ratio=p.get("mesh_damping_ratio", 0.05) if p.get("contact_damping", True) else 0.0,
                      mu=p.get("mu", 0.002) if p.get("friction", True) else 0.0)
        self.stage = make_stage(fid, stage_params=sp, **kw)
        self.inputs = dict(flange_a_phi=0.0, flange_a_w=0.0, flange_b_phi=0.0, flange_b_w=0.0)
        # the assembled port twists (the FMU's initial_state: each body at its flange plus the twist)
        self.twist = (float(p.get("twist_a_start", 0.0)), float(p.get("twist_b_start", 0.0)))

    def init(self):
        i = self.inputs
        self.stage.initialize(0.0, i["flange_a_phi"], i["flange_a_w"], i["flange_b_phi"], i["flange_b_w"],
                              theta_pinion=i["flange_a_phi"] + self.twist[0],
                              theta_wheel=i["flange_b_phi"] + self.twist[1])

    def step(self, t, H):
        i = self.inputs
        self.stage.step(t, H, i["flange_a_phi"], i["flange_a_w"], i["flange_b_phi"], i["flange_b_w"])

    def outputs(self):
        st = self.stage
        return {"flange_a_tau": st.tau_a, "flange_b_tau": st.tau_b, "flange_a_tau_mean": st.tau_a_mean,
                "flange_b_tau_mean": st.tau_b_mean,
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
                if p.kind == SPRING:
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


def set_state_from_vector(loop: Loop, labels, x, v=None):
    """Set every node angle (and speed) from a global vector over ``labels`` ("component.node", as in
    drivetrain.eigen.assemble_linear), then redo the initial exchange."""
    idx = {lbl: i for i, lbl in enumerate(labels)}
    for name, c in loop.comps.items():
        if isinstance(c, _Gear):
            st = c.stage
            if f"{name}.pinion+wheel" in idx:
                tp = float(x[idx[f"{name}.pinion+wheel"]])
                wp = 0.0 if v is None else float(v[idx[f"{name}.pinion+wheel"]])
                c._init_state = dict(theta_pinion=tp, omega_pinion=wp)
            else:
                c._init_state = dict(theta_pinion=float(x[idx[f"{name}.pinion"]]),
                                     theta_wheel=float(x[idx[f"{name}.wheel"]]),
                                     omega_pinion=0.0 if v is None else float(v[idx[f"{name}.pinion"]]),
                                     omega_wheel=0.0 if v is None else float(v[idx[f"{name}.wheel"]]))
            continue
        ln = c.line
        th = np.array([x[idx[f"{name}.{nn}"]] for nn in ln.node_names])
        om = np.zeros(ln.n) if v is None else np.array([v[idx[f"{name}.{nn}"]] for nn in ln.node_names])
        ln.set_state(th, om, float(ln.pi_x[0]))
    loop.out = {n: loop._outputs(n, initial=True) for n in loop.comps}
    loop._exchange()
    for name, c in loop.comps.items():
        if isinstance(c, _Gear):
            i = c.inputs
            c.stage.initialize(0.0, i["flange_a_phi"], i["flange_a_w"], i["flange_b_phi"], i["flange_b_w"],
                               **getattr(c, "_init_state", {}))
    loop.out = {n: loop._outputs(n, initial=True) for n in loop.comps}


def fit_damped_sine(t, y, f0):
    """Least-squares fit y = c + A exp(-s t) cos(2 pi f t + p); returns (f, zeta, fit residual rms / A)."""
    from scipy.optimize import curve_fit

    y = np.asarray(y, dtype=float)
    c0 = float(np.mean(y[-len(y) // 4:]))
    A0 = float(np.max(np.abs(y - c0)))

    def model(tt, c, A, s, f, p):
        return c + A * np.exp(-s * tt) * np.cos(2 * np.pi * f * tt + p)

    best = None
    for p0 in (0.0, np.pi / 2, np.pi, -np.pi / 2):
        try:
            popt, _ = curve_fit(model, t, y, p0=[c0, A0, 1.0, f0, p0], maxfev=20000)
        except RuntimeError:
            continue
        r = float(np.sqrt(np.mean((model(t, *popt) - y) ** 2)))
        if best is None or r < best[1]:
            best = (popt, r)
    popt, r = best
    c, A, s, f, p = popt
    wd = 2 * np.pi * abs(f)
    zeta = s / np.sqrt(s * s + wd * wd)
    return abs(f), float(zeta), r / abs(A)
