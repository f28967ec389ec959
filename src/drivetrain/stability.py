"""Is the co-simulation stable and in range before any step? The checks of every cut of a SystemSpec.

- ``check_cuts``: per connection, the exact one-step map of the isolated cut (the spring side's body
  with its port spring, the inertia side under the held torque, the coupling actually used) and its
  spectral radius; with ``whole_system`` also the radius of the whole linearised co-simulation
  (``eigen.cosim_radius``). Raises ``UnstableCutError`` naming the cut and the numbers.
- ``check_contact_range``: whether the static load alone would drive a table/pcm gear contact past
  its maximum penetration u_max (an error state of the PCM model). Raises ``ContactRangeError``.

Why (the coupling analysis and its measured limits): docs/STABILITY.md and docs/MASTER.md.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass

import numpy as np
from scipy.linalg import expm

from drivetrain import eigen
from drivetrain.errors import ContactRangeError, UnstableCutError  # noqa: F401  (raised here)
from gearcontact_fmu.params import BevelGearParams, MeshResolution, PCMParams

# gearcontact_fmu.contact_map (the PCM engine) is imported by check_contact_range only for table/pcm gears


def two_body_map(Ja: float, Jb: float, k: float, d: float, H: float, output: str = "predicted") -> np.ndarray:
    """Exact one-step map of the isolated cut: the spring-side body Ja with the port spring (k, d),
    the flange angle extrapolated linearly with the received speed; the inertia-side body Jb under the
    held torque (Jacobi, zero-order hold). State [q = th_a - th_b, w_a, w_b, tau]. ``output``: the
    spring side's torque output (predicted | mean | end, as in components/stage)."""

    A = np.zeros((5, 5))
    A[0, 1] = 1.0
    A[1, 0] = -k / Ja
    A[1, 1] = -d / Ja
    A[1, 2] = k / Ja
    A[1, 3] = d / Ja
    A[2, 3] = 1.0
    A[4, 0] = k
    A[4, 1] = d
    A[4, 2] = -k
    A[4, 3] = -d
    E = expm(A * H)
    Z0 = np.zeros((5, 4))
    Z0[0, 0] = 1.0
    Z0[1, 1] = 1.0
    Z0[3, 2] = 1.0
    Z1 = E @ Z0
    T = np.zeros((4, 4))
    thb1 = np.array([0.0, 0.0, H, H * H / (2.0 * Jb)])
    wb1 = np.array([0.0, 0.0, 1.0, H / Jb])
    T[0] = Z1[0] - thb1
    T[1] = Z1[1]
    T[2] = wb1
    defl = Z1[0] - Z1[2]
    rel = Z1[1] - Z1[3]
    if output == "mean":
        T[3] = Z1[4] / H
    else:
        tend = k * defl + d * rel
        if output == "end":
            T[3] = tend
        else:
            T[3] = tend + 0.5 * H * (k * rel + d * (-k * defl - d * rel) / Ja)
    return T


def two_body_radius(Ja, Jb, k, d, H, output="predicted") -> float:
    """Spectral radius of the cut's one-step map, the uniform-rotation eigenvalue (exactly 1) excluded."""
    ev = np.linalg.eigvals(two_body_map(Ja, Jb, k, d, H, output))
    mag = np.abs(ev)
    i1 = int(np.argmin(np.abs(ev - 1.0)))
    if abs(ev[i1] - 1.0) < 1e-9:
        mag = np.delete(mag, i1)
    return float(mag.max())


@dataclass
class CutReport:
    spring: str
    inertia: str
    k: float                  # port spring in the flange frame
    c: float
    J_spring: float           # spring-side inertia at the port, flange frame
    J_inertia: float          # inertia-side inertia at the port, flange frame
    H: float
    omega_if: float           # sqrt(k (1/J_spring + 1/J_inertia)) [rad/s]
    zeta: float
    radius: float             # spectral radius of the exact two-body cut map
    output: str
    stable: bool

    @property
    def f_if(self) -> float:
        return self.omega_if / (2.0 * math.pi)

    @property
    def wH(self) -> float:
        return self.omega_if * self.H

    def line(self) -> str:
        return (f"{self.spring} -> {self.inertia}: k = {self.k:.6g} N m/rad, c = {self.c:.3g} N m s/rad, "
                f"J_spring = {self.J_spring:.4g}, J_inertia = {self.J_inertia:.4g} kg m^2 "
                f"(ratio {self.J_inertia / self.J_spring:.3g}), f_if = {self.f_if:.1f} Hz, "
                f"omega_if*H = {self.wH:.3f}, zeta = {self.zeta:.3f}, spectral radius = {self.radius:.6f} "
                f"({'stable' if self.stable else 'UNSTABLE'})")

    def as_dict(self) -> dict:
        return {"spring": self.spring, "inertia": self.inertia, "k": self.k, "c": self.c,
                "J_spring": self.J_spring, "J_inertia": self.J_inertia, "f_if_Hz": self.f_if,
                "omega_if_H": self.wH, "zeta": self.zeta, "radius": self.radius, "stable": self.stable}


def cut_report(spring: str, inertia: str, k: float, c: float, J_spring: float, J_inertia: float, H: float,
               output: str = "predicted", tol: float = 1e-9) -> CutReport:
    w = math.sqrt(k * (1.0 / J_spring + 1.0 / J_inertia))
    zeta = c * w / (2.0 * k) if k > 0 else 0.0
    rho = two_body_radius(J_spring, J_inertia, k, c, H, output)
    return CutReport(spring, inertia, k, c, J_spring, J_inertia, H, w, zeta, rho, output, rho <= 1.0 + tol)


def check_contact_range(spec, raise_on_error: bool = True) -> list[dict]:
    """Predict, before any step, whether the static load alone drives a GearContact of fidelity
    ``table`` or ``pcm`` beyond its maximum penetration u_max (an error state of the PCM model that
    would stop the run at the first loaded step).

    The static pinion torque is the middle-shaft torque of the spec's steady state (metadata
    ``steady_state.T_msh``, the assembler's torque balance at the scene's operating point); the
    largest penetration over a pinion revolution at that torque comes from the contact map of the
    component's geometry, resolution and health (:func:`gearcontact_fmu.contact_map.static_penetration`;
    for ``table`` the map the run uses, built and cached here if missing; for ``pcm`` only a cached one).
    Dynamic peaks come on top and
    are caught at run time. Returns one report per checked gear; raises ContactRangeError naming the
    component, u_max, the predicted penetration and the torque when u_max is below it."""
    import dataclasses

    ss = (spec.metadata or {}).get("steady_state") or {}
    T = ss.get("T_msh")
    reports, problems = [], []
    gears = [c for c in spec.components if c.model == "GearContact"
             and str(c.parameters.get("fidelity", "")).strip().lower() in ("table", "pcm")]
    if T is None or not gears:
        return reports
    # only now: an ideal or analytic gear loads no contact engine
    from gearcontact_fmu.contact_map import get_map, static_penetration
    from gearcontact_fmu.gearpair import fault_kwargs_of

    for comp in gears:
        p = comp.parameters
        pick = (lambda cls: cls(**{f.name: p[f.name] for f in dataclasses.fields(cls) if f.name in p}))
        gear, pcm = pick(BevelGearParams), pick(PCMParams)
        base = MeshResolution()
        res = MeshResolution(profile=float(p.get("profile_element_size", base.profile)),
                             face=float(p.get("face_element_size", base.face)))
        files = {k: p[f"{k}_mesh_file"] for k in ("pinion", "wheel") if p.get(f"{k}_mesh_file")}
        # the elastic response does not depend on u_max, but the map's search length (2 u_max) does:
        # predict with a search long enough to see the penetration (the default map when u_max is smaller)
        search = dataclasses.replace(pcm, u_max=max(pcm.u_max, PCMParams().u_max))
        # a table gear builds its map anyway (the run uses it); a pcm gear is predicted only from a
        # cached map of its geometry, never by building one just for the check
        fidelity = str(p.get("fidelity")).strip().lower()
        health = str(p.get("health", "healthy"))
        cmap = get_map(gear, search, res, health, files or None, mesh_units=str(p.get("mesh_units", "mm")),
                       build=fidelity == "table",
                       fault_kwargs=fault_kwargs_of(health, json.loads(p.get("faults") or "[]")))
        if cmap is None:
            reports.append({"component": comp.name, "pinion_torque_Nm": float(T), "static_penetration_m": None,
                            "u_max_m": pcm.u_max, "note": "not predicted: no contact map of this geometry cached"})
            continue
        u, theta = static_penetration(cmap, float(T))
        rep = {"component": comp.name, "pinion_torque_Nm": float(T), "static_penetration_m": u,
               "at_pinion_angle_deg": math.degrees(theta), "u_max_m": pcm.u_max}
        reports.append(rep)
        if math.isfinite(u) and u >= pcm.u_max:
            problems.append(f"{comp.name}: u_max = {pcm.u_max:.4g} m is below the static penetration "
                            f"{u:.4g} m at the steady pinion torque {T:.4g} N·m (pinion angle "
                            f"{math.degrees(theta):.1f} deg): the mesh would enter its error state at the "
                            f"first loaded step; raise u_max or lower the load")
    if problems and raise_on_error:
        raise ContactRangeError(problems)
    return reports


def check_cuts(spec, raise_on_unstable: bool = True, whole_system: bool = True):
    """Check every connection of a SystemSpec at its communication step.

    Per cut: the port spring (k, c) in the flange frame, the spring-side inertia at the port (for the
    gear stage the pinion and the wheel referred to that flange: the mesh is far stiffer than the
    port) and the inertia-side inertia, omega_if = sqrt(k (1/J_s + 1/J_i)) (notes section 1; the ratio
    enters through the flange-frame referral), omega_if H, the damping ratio, and the spectral radius
    of the exact one-step map of the isolated cut under the coupling actually used (Jacobi, held
    torque, spring side extrapolating the received angle with the received speed, its torque output
    as configured). With ``whole_system`` also the spectral radius of the one-step map of the whole
    linearised co-simulation (drivetrain.eigen.cosim_radius). Raises UnstableCutError (naming the cut
    and the numbers) unless every radius is <= 1. Returns (reports, whole_system_radius or None)."""
    blocks = eigen.blocks_from_spec(spec)
    reports = []
    problems = []
    H = float(spec.comm_step)
    for conn in spec.connections:
        sc, sp = conn.spring.split(".", 1)
        ic, ip = conn.inertia.split(".", 1)
        bs, bi = blocks[sc], blocks[ic]
        ps, pi = bs.port(sp), bi.port(ip)
        Js = bs.port_inertia(sp)
        Ji = bi.port_inertia(ip)
        out = bs.output_torque
        rep = cut_report(conn.spring, conn.inertia, ps.k, ps.c, Js, Ji, H, out)
        reports.append(rep)
        if not rep.stable:
            problems.append(f"cut {rep.line()}; choose a softer cut element, put the heavier body on the "
                            f"inertia side, or reduce the communication step")
    rho = None
    if whole_system:
        rho = eigen.cosim_radius(spec, blocks=blocks)
        if rho > 1.0 + 1e-9:
            problems.append(f"the whole co-simulated system is unstable at H = {H:.6g} s: spectral radius "
                            f"of the one-step map {rho:.6f} > 1")
    if problems and raise_on_unstable:
        raise UnstableCutError(problems, reports)
    return reports, rho
