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

import dataclasses
import json
import math
import time
from dataclasses import dataclass

import numpy as np
from scipy.linalg import expm

from drivetrain.models import eigen
from drivetrain.errors import ContactCostError, ContactRangeError, UnstableCutError  # noqa: F401
from gearcontact_fmu.mesh_models import DEFAULT_FIDELITY
from gearcontact_fmu.params import GEAR_MODEL, BevelGearParams, MapGrid, MeshResolution, PCMParams

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


def contact_gears(spec) -> list:
    """The GearContact components of a spec whose fidelity evaluates the PCM engine (table or pcm)."""
    return [c for c in spec.components_of(GEAR_MODEL)
            if str(c.parameters.get("fidelity", DEFAULT_FIDELITY)).strip().lower() in ("table", "pcm")]


def contact_inputs(comp) -> dict:
    """What a GearContact component's contact model is built from, read from its parameters once."""
    from gearcontact_fmu.mesh_models.pcm import fault_kwargs_of
    from gearcontact_fmu.stage import StageParams

    p = comp.parameters
    pick = (lambda cls: cls(**{f.name: p[f.name] for f in dataclasses.fields(cls) if f.name in p}))
    base, grid = MeshResolution(), MapGrid()
    health = str(p.get("health", "healthy"))
    return {"gear": pick(BevelGearParams), "pcm": pick(PCMParams),
            "resolution": MeshResolution(profile=float(p.get("profile_element_size", base.profile)),
                                         face=float(p.get("face_element_size", base.face))),
            "files": {k: p[f"{k}_mesh_file"] for k in ("pinion", "wheel") if p.get(f"{k}_mesh_file")},
            "fidelity": str(p.get("fidelity")).strip().lower(), "health": health,
            "mesh_units": str(p.get("mesh_units", "mm")),
            "fault_kwargs": fault_kwargs_of(health, json.loads(p.get("faults") or "[]")),
            "grid": MapGrid(points_per_pitch=int(p.get("map_points_per_pitch", grid.points_per_pitch)),
                            s_points=int(p.get("map_approach_points", grid.s_points))),
            "max_substep": float(p.get("max_substep", StageParams().max_substep))}


#: a contact model estimated to take longer than this is announced before the run [s]
COSTLY_CONTACT_S = 600.0


def check_contact_cost(spec, duration_s: float, max_hours: float) -> list[dict]:
    """Estimate, before any step, what each table/pcm gear's contact model will cost, and refuse a run
    whose estimate exceeds ``max_hours`` (ContactCostError naming the component, the triangle count,
    the estimate and how to coarsen).

    Only geometry whose cost is not known beforehand is probed: mesh files, or element sizes finer
    than the default resolution. A generated mesh is first counted without being built
    (:func:`gearcontact_fmu.cost.predicted_triangles`); past the budget at the measured growth law
    of the default pair it is refused without being built. Otherwise the pair is built and timed on
    this machine (:func:`gearcontact_fmu.cost.probe`): a table gear pays the rows of its map not yet
    cached, a pcm gear 4 evaluations per sub-step of the run. Returns one report per probed gear
    (``estimate_s``, ``triangles``, ``warning`` when the estimate exceeds COSTLY_CONTACT_S)."""
    gears = contact_gears(spec)
    if not gears:
        return []
    from gearcontact_fmu import cost
    from gearcontact_fmu.contact_map import get_map, map_workers, pairing_revolutions, wheel_faults
    from gearcontact_fmu.mesh_models.pcm import build_pcm_pair
    from gearcontact_fmu.params import substeps

    ss = (spec.metadata or {}).get("steady_state") or {}
    w_pinion = abs(float(ss.get("w_middle", 0.0) or 0.0))
    H = float(spec.comm_step)
    budget = max_hours * 3600.0
    reports, problems = [], []
    for comp in gears:
        inp = contact_inputs(comp)
        gear, res, files = inp["gear"], inp["resolution"], inp["files"]
        finer = res.profile < MeshResolution().profile * (1 - 1e-9) or res.face < MeshResolution().face * (1 - 1e-9)
        if not files and not finer:
            continue
        n_sub = duration_s / H * substeps(H, inp["max_substep"]) if inp["fidelity"] == "pcm" else 0.0
        n_rev = pairing_revolutions(gear, not (wheel_faults(inp["health"], inp["fault_kwargs"]) or "wheel" in files))
        # user meshes are computed row by row; generated ones tile their healthy pitch blocks
        blocks = gear.z_pinion * n_rev if files else 1 + 3 * len((inp["fault_kwargs"] or {}).get("faults", []))
        map_rows = blocks * inp["grid"].points_per_pitch        # what a table gear of this geometry computes
        rows = 0
        if inp["fidelity"] == "table":
            if get_map(gear, inp["pcm"], res, inp["health"], files or None, mesh_units=inp["mesh_units"],
                       build=False, fault_kwargs=inp["fault_kwargs"], grid=inp["grid"]) is not None:
                continue                                   # cached: the run pays nothing for it
            rows = map_rows
        what = (" and ".join(f"{k} mesh {v}" for k, v in files.items()) if files else
                f"generated meshes at {res.profile * 1e3:g} mm x {res.face * 1e3:g} mm elements")
        if not files:
            n_tri = cost.predicted_triangles(gear, res)
            t0 = time.perf_counter()
            ref = build_pcm_pair(gear, inp["pcm"], MeshResolution())
            build_s = time.perf_counter() - t0
            ref_cost = cost.estimate(sum(ref.info.values()), build_s=build_s, map_rows=rows,
                                     map_workers=map_workers(), n_substeps=n_sub,
                                     **_probe(ref, w_pinion, inp["max_substep"], H, n_sub > 0))
            guess = cost.scaled(ref_cost, n_tri)
            memory = cost.available_memory_bytes()
            if guess.total_s > 4 * budget or (memory and guess.memory_bytes > 0.5 * memory):
                # refused before a mesh of this size is built
                problems.append(_cost_problem(comp.name, what, guess, budget, res, map_rows, memory))
                reports.append(_cost_report(comp.name, guess, "predicted"))
                continue
        t0 = time.perf_counter()
        pair = build_pcm_pair(gear, inp["pcm"], res, inp["health"], files.get("pinion"), files.get("wheel"),
                              inp["mesh_units"], fault_kwargs=inp["fault_kwargs"])
        est = cost.estimate(sum(pair.info.values()), build_s=time.perf_counter() - t0, map_rows=rows,
                            map_workers=map_workers(), n_substeps=n_sub,
                            **_probe(pair, w_pinion, inp["max_substep"], H, n_sub > 0))
        del pair
        rep = _cost_report(comp.name, est, "measured")
        if est.total_s > budget:
            problems.append(_cost_problem(comp.name, what, est, budget, None if files else res, map_rows, None))
        elif est.total_s > COSTLY_CONTACT_S:
            rep["warning"] = (f"{comp.name}: the contact model of {what} ({est.triangles:,} triangles) will take "
                              f"about {cost.hours(est.total_s)}")
        reports.append(rep)
    if problems:
        raise ContactCostError(problems)
    return reports


def _probe(pair, w_pinion, max_substep, H, online: bool) -> dict:
    """The measured costs of a pair; the online sub-steps only for a gear that runs online (pcm)."""
    from gearcontact_fmu import cost
    from gearcontact_fmu.params import substeps

    row_s, sub_s = cost.probe(pair, w_pinion, H / substeps(H, max_substep), n_substeps=100 if online else 0)
    return {"row_s": row_s, "substep_s": sub_s}


def _cost_report(name, est, how) -> dict:
    return {"component": name, "triangles": est.triangles, "estimate_s": est.total_s,
            "map_build_s": est.map_build_s, "loop_s": est.loop_s, "how": how}


def _cost_problem(name, what, est, budget_s, res, map_rows, memory) -> str:
    """The refusal: the estimate, where it comes from, and how to bring it within the budget (time, and
    ``memory`` the available bytes when that is what the meshes would not fit)."""
    from gearcontact_fmu import cost

    n_fit = cost.fitting_triangles(est, 0.5 * budget_s)
    if memory and est.memory_bytes > 0.5 * memory:
        n_fit = min(n_fit, int(0.25 * memory / cost.BYTES_PER_TRIANGLE))
    parts = [f"meshes {cost.hours(est.build_s)}"] if est.build_s >= 1 else []
    if est.map_build_s:
        parts.append(f"contact map {cost.hours(est.map_build_s)}")
    if est.loop_s:
        parts.append(f"online PCM {cost.hours(est.loop_s)}")
    if res is not None:
        r = est.triangles / max(n_fit, 1)               # the factor the element area must grow by
        face = min(max(res.face, MeshResolution().face), res.face * r)   # the face first, up to the default
        profile = res.profile * r * res.face / face
        how = (f"raise the element sizes, e.g. numerics.profile_element_mm = {profile * 1e3:.3g} and "
               f"face_element_mm = {face * 1e3:.3g}")
    else:
        how = ("coarsen the mesh files (e.g. trimesh's simplify_quadric_decimation, or re-export with "
               "larger elements: about 0.05 mm along the profile and 2 mm along the face are converged)")
    if est.loop_s:         # an online gear: the table fidelity pays the mesh once, in its cached map
        from gearcontact_fmu.contact_map import map_workers

        table_s = map_rows * est.row_s / map_workers()
        how += (f"; or use effects.mesh_contact = \"table\": its contact map of this mesh takes about "
                f"{cost.hours(table_s)} once (then cached), and its run does not depend on the mesh size")
    if memory and est.memory_bytes > 0.5 * memory:
        over = (f"needs about {est.memory_bytes / 1e9:.3g} GB of memory, more than half of the "
                f"{memory / 1e9:.3g} GB available")
        return (f"{name}: the contact model of {what} would have about {est.triangles:,} triangles and "
                f"{over} (and would take about {cost.hours(est.total_s)}). Use at most ~{n_fit:,} triangles: {how}")
    return (f"{name}: the contact model of {what} has about {est.triangles:,} triangles and would take about "
            f"{cost.hours(est.total_s)} ({', '.join(parts)}; measured on this machine), over the limit "
            f"numerics.max_contact_hours = {budget_s / 3600:g} h. To bring it to about half the limit, use at "
            f"most ~{n_fit:,} triangles: {how}; or raise numerics.max_contact_hours to run it anyway")


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
    ss = (spec.metadata or {}).get("steady_state") or {}
    T = ss.get("T_msh")
    reports, problems = [], []
    gears = contact_gears(spec)
    if T is None or not gears:
        return reports
    # only now: an ideal or analytic gear loads no contact engine
    from gearcontact_fmu.contact_map import get_map, static_penetration

    for comp in gears:
        inp = contact_inputs(comp)
        gear, pcm, res, files, health = inp["gear"], inp["pcm"], inp["resolution"], inp["files"], inp["health"]
        fidelity = inp["fidelity"]
        # the elastic response does not depend on u_max, but the map's search length (2 u_max) does:
        # predict with a search long enough to see the penetration (the default map when u_max is smaller)
        search = dataclasses.replace(pcm, u_max=max(pcm.u_max, PCMParams().u_max))
        # a table gear builds its map anyway (the run uses it); a pcm gear is predicted only from a
        # cached map of its geometry, never by building one just for the check
        cmap = get_map(gear, search, res, health, files or None, mesh_units=inp["mesh_units"],
                       build=fidelity == "table", fault_kwargs=inp["fault_kwargs"], grid=inp["grid"])
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
    linearised co-simulation (drivetrain.models.eigen.cosim_radius). Raises UnstableCutError (naming the cut
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
