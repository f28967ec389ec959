"""Natural frequencies of the assembled, linearised drivetrain, and the stability of its co-simulation.

Every component of a SystemSpec becomes a :class:`LinearBlock` (mass, stiffness and damping matrices of
its nodes in their own frames, and its flange ports); the connections add the port springs between
the nodes they join, through the port ratios (a flange angle is ``ratio * node angle``). Working in the
nodes' own frames is the same generalised eigenproblem as referring everything to the drive shaft
(J R^2, k R^2): the two differ by a diagonal change of coordinates. The lower gear mesh is a spring of
the ISO 6336 mean mesh stiffness (gearcontact_fmu.mesh_models.analytic) for the compliant fidelities, rigid for
``ideal`` (or as asked with ``gear=``).

:func:`cosim_radius` builds the one-step map of the whole linearised co-simulation (each FMU integrated
exactly over H with its inputs held / extrapolated as the FMUs do, Jacobi exchange, the spring sides'
torque output as configured) and returns its spectral radius: < 1 means the coupled system is stable
at that H.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from drivetrain.models.components import COMPONENTS, make_component

from drivetrain.models.line import loss_slope
from drivetrain.rig.data import PublicModel, default_parameters, public_matrices
from drivetrain.system import SPRING, SystemSpec
from gearcontact_fmu.mesh_models import DEFAULT_FIDELITY
from gearcontact_fmu.mesh_models.analytic import mesh_stiffness
from gearcontact_fmu.fmu_variables import gear_pair
from gearcontact_fmu.params import GEAR_MODEL



@dataclass
class BlockPort:
    name: str
    node: int
    kind: int
    ratio: float = 1.0
    k: float = 0.0
    c: float = 0.0


@dataclass
class LinearBlock:
    name: str
    model: str
    M: np.ndarray
    K: np.ndarray
    C: np.ndarray
    ports: dict
    node_names: list
    output_torque: str = "predicted"
    port_J: dict = field(default_factory=dict)       # flange-frame inertia seen at a port (cut checks)
    K_ground: np.ndarray | None = None               # linearised controller (spring to ground)
    C_ground: np.ndarray | None = None               # linearised losses and controller (damping to ground)

    def port(self, name: str) -> BlockPort:
        try:
            return self.ports[name]
        except KeyError:
            raise KeyError(f"{self.name} ({self.model}) has no port {name!r}; ports: {sorted(self.ports)}") from None

    def port_inertia(self, name: str) -> float:
        if name in self.port_J:
            return self.port_J[name]
        p = self.port(name)
        return float(self.M[p.node, p.node]) / p.ratio ** 2

    @property
    def n(self) -> int:
        return self.M.shape[0]


def _gear_mesh_stiffness(params: dict) -> float:
    """ISO 6336 mean mesh stiffness of the pair the parameters name (the rig's where they name none), pinion
    frame [N m/rad]."""
    return float(mesh_stiffness(gear_pair(params))["K_mean"])


def gear_block(name: str, params: dict, gear: str = "auto") -> LinearBlock:
    """Linear model of the GearContact stage: pinion and wheel (or one rigid body for the ideal gear),
    port springs k_a, k_b, the mesh as a spring of the mean mesh stiffness."""

    p = dict(default_parameters(GEAR_MODEL))
    p.update({k: v for k, v in params.items()})
    Jp, Jw = float(p["J_pinion"]), float(p["J_wheel"])
    r = gear_pair(p).ratio
    fid = str(p.get("fidelity", DEFAULT_FIDELITY)).lower()
    rigid = (gear == "rigid") or (gear == "auto" and fid == "ideal")
    out = str(p.get("output_torque", "predicted"))
    if rigid:
        M = np.array([[Jp + Jw / r ** 2]])
        K = np.zeros((1, 1))
        C = np.zeros((1, 1))
        ports = {"flange_a": BlockPort("flange_a", 0, SPRING, 1.0, p["k_a"], p["d_a"]),
                 "flange_b": BlockPort("flange_b", 0, SPRING, 1.0 / r, p["k_b"], p["d_b"])}
        names = ["pinion+wheel"]
    else:
        Km = _gear_mesh_stiffness(p) if gear in ("auto", "analytic") else float(gear)
        zeta = float(p.get("mesh_damping_ratio", 0.05))
        Jred = 1.0 / (1.0 / Jp + 1.0 / (Jw / r ** 2))
        cm = 2.0 * zeta * math.sqrt(Km * Jred)
        v = np.array([1.0, -r])
        M = np.diag([Jp, Jw])
        K = Km * np.outer(v, v)
        C = cm * np.outer(v, v)
        ports = {"flange_a": BlockPort("flange_a", 0, SPRING, 1.0, p["k_a"], p["d_a"]),
                 "flange_b": BlockPort("flange_b", 1, SPRING, 1.0, p["k_b"], p["d_b"])}
        names = ["pinion", "wheel"]
    # the mesh is far stiffer than the ports: each port sees pinion and wheel together
    port_J = {"flange_a": Jp + Jw / r ** 2, "flange_b": Jw + Jp * r ** 2}
    return LinearBlock(name, GEAR_MODEL, M, K, C, ports, names, out, port_J)


def component_block(name: str, model: str, params: dict, operating: bool = True) -> LinearBlock:
    """Linear model of one of the drivetrain components (drivetrain.models.components)."""

    comp = make_component(model, params)
    ln = comp.line
    M, K, C = ln.linear_matrices()
    ports = {p.name: BlockPort(p.name, p.node, p.kind, p.ratio, p.k, p.c)
             for p in ln.ports}
    n = ln.n
    Kg = np.zeros((n, n))
    Cg = np.zeros((n, n))
    if operating:
        # small-signal losses at the initial (operating) speed and the PI controller
        for q, lw in enumerate(ln.laws):
            j = lw.node
            w = float(ln.om[j])
            Cg[j, j] += float(loss_slope(w, 0.0, ln.l_cv[q], ln.l_Tc[q], ln.l_wc[q], 0.0))
        if ln.motor_node >= 0:
            Kp, Ti = float(ln.m_par[0]), float(ln.m_par[1])
            Cg[ln.motor_node, ln.motor_node] += Kp
            Kg[ln.motor_node, ln.motor_node] += Kp / Ti
    return LinearBlock(name, model, M, K, C, ports, list(ln.node_names), ln.output_torque, {}, Kg, Cg)


def blocks_from_spec(spec: SystemSpec, gear: str = "auto", operating: bool = True) -> dict:
    out = {}
    for c in spec.components:
        if c.model == GEAR_MODEL:
            out[c.name] = gear_block(c.name, c.parameters, gear)
        elif c.model in COMPONENTS:
            out[c.name] = component_block(c.name, c.model, c.parameters, operating)
        else:
            raise ValueError(f"component {c.name!r}: no linear model for FMU model {c.model!r}")
    return out


@dataclass
class LinearSystem:
    M: np.ndarray
    K: np.ndarray
    C: np.ndarray
    labels: list                   # "component.node"
    R: np.ndarray                  # speed ratio of each node relative to the first component's first node
    K_ground: np.ndarray
    C_ground: np.ndarray


def assemble_linear(spec: SystemSpec, gear: str = "auto", blocks: dict | None = None,
                    operating: bool = True) -> LinearSystem:
    """Global (M, K, C) in the nodes' own frames; R refers each node to the drive shaft."""
    blocks = blocks or blocks_from_spec(spec, gear, operating)
    offs = {}
    n = 0
    labels = []
    for name, b in blocks.items():
        offs[name] = n
        n += b.n
        labels += [f"{name}.{nn}" for nn in b.node_names]
    M = np.zeros((n, n))
    K = np.zeros((n, n))
    C = np.zeros((n, n))
    Kg = np.zeros((n, n))
    Cg = np.zeros((n, n))
    for name, b in blocks.items():
        o = offs[name]
        s = slice(o, o + b.n)
        M[s, s] += b.M
        K[s, s] += b.K
        C[s, s] += b.C
        if b.K_ground is not None:
            Kg[s, s] += b.K_ground
        if b.C_ground is not None:
            Cg[s, s] += b.C_ground
    # connections: port spring between r_s theta_s and r_i theta_i
    edges = []
    for conn in spec.connections:
        sc, sp = conn.spring.split(".", 1)
        ic, ip = conn.inertia.split(".", 1)
        ps, pi = blocks[sc].port(sp), blocks[ic].port(ip)
        a, bb = offs[sc] + ps.node, offs[ic] + pi.node
        v = np.zeros(n)
        v[a] += ps.ratio
        v[bb] -= pi.ratio
        K += ps.k * np.outer(v, v)
        C += ps.c * np.outer(v, v)
        edges.append((a, bb, pi.ratio / ps.ratio))
    # speed ratio of each node relative to the first node: through internal couplings (same frame,
    # or the mesh ratio in the gear) and through the connections (r_s theta_a = r_i theta_b)
    R = np.full(n, np.nan)
    R[0] = 1.0
    links = []
    for name, b in blocks.items():
        o = offs[name]
        for i in range(b.n):
            for j in range(i + 1, b.n):
                if b.K[i, j] != 0 or b.M[i, j] != 0:
                    f = 1.0
                    if b.model == GEAR_MODEL:
                        f = -b.K[i, i] / b.K[i, j]          # speed(wheel) / speed(pinion) = 1/r
                    links.append((o + i, o + j, f))
    for a, bb, rr in edges:
        links.append((a, bb, 1.0 / rr))                  # speed(b) = speed(a) r_s / r_i
    for _ in range(n + 1):
        changed = False
        for a, bb, f in links:
            if np.isnan(R[bb]) and not np.isnan(R[a]):
                R[bb] = R[a] * f
                changed = True
            elif np.isnan(R[a]) and not np.isnan(R[bb]):
                R[a] = R[bb] / f
                changed = True
        if not changed:
            break
    return LinearSystem(M, K, C, labels, R, Kg, Cg)


def modes(spec, gear: str = "auto", controller: bool = False, damped: bool = False):
    """Natural frequencies [Hz] (ascending, rigid-body mode removed) and mode shapes of the assembled
    drivetrain. ``controller``: include the linearised PI speed controller and the small-signal losses
    at the operating speed (then there is no rigid-body mode). ``damped``: also return damping ratios
    from the state-space eigenvalues. Returns (f, shapes[, zeta]) with shapes in the nodes' own frames."""
    from scipy.linalg import eigh

    spec = _as_spec(spec)
    ls = assemble_linear(spec, gear, operating=controller)
    K = ls.K + (ls.K_ground if controller else 0.0)
    w2, V = eigh(K, ls.M)
    keep = w2 > (2 * math.pi * 0.05) ** 2 if not controller else w2 > -1.0
    f = np.sqrt(np.abs(w2[keep])) / (2 * math.pi)
    V = V[:, keep]
    if not damped:
        return f, V, ls
    C = ls.C + (ls.C_ground if controller else 0.0)
    n = ls.M.shape[0]
    Mi = np.linalg.inv(ls.M)
    A = np.block([[np.zeros((n, n)), np.eye(n)], [-Mi @ K, -Mi @ C]])
    lam = np.linalg.eigvals(A)
    lam = lam[np.imag(lam) > 1e-6]
    lam = lam[np.argsort(np.abs(lam))]
    wn = np.abs(lam)
    zeta = -np.real(lam) / wn
    return f, V, ls, wn / (2 * math.pi), zeta


def damped_modes(spec, gear: str = "auto", controller: bool = False):
    """Complex modes of the damped linearised drivetrain: (lam, psi, ls) with the eigenvalues lam
    (Im > 0, ascending damped frequency Im(lam)/2pi) and the state-space eigenvectors psi = [x; v] (the
    real part of psi is an initial state that excites that mode alone), rigid-body modes removed."""
    spec = _as_spec(spec)
    ls = assemble_linear(spec, gear, operating=controller)
    K = ls.K + (ls.K_ground if controller else 0.0)
    C = ls.C + (ls.C_ground if controller else 0.0)
    n = ls.M.shape[0]
    Mi = np.linalg.inv(ls.M)
    A = np.block([[np.zeros((n, n)), np.eye(n)], [-Mi @ K, -Mi @ C]])
    lam, psi = np.linalg.eig(A)
    keep = np.imag(lam) > 2 * math.pi * 0.05
    lam, psi = lam[keep], psi[:, keep]
    o = np.argsort(np.imag(lam))
    return lam[o], psi[:, o], ls


def natural_frequencies(spec, gear: str = "auto", controller: bool = False) -> np.ndarray:
    """Undamped natural frequencies [Hz] of the assembled, linearised drivetrain (rigid-body mode
    removed) of a SystemSpec."""
    return modes(spec, gear, controller)[0]


def _as_spec(obj) -> SystemSpec:
    if isinstance(obj, SystemSpec):
        return obj
    raise TypeError(f"expected a SystemSpec, not {type(obj).__name__}; assemble a scene first "
                    "(drivetrain.run.assemble.assemble(scene, check=False))")


# ------------------------------------------------------------------------------------------------
# Co-simulation stability: one-step map of the whole linearised system
# ------------------------------------------------------------------------------------------------

def cosim_map(spec: SystemSpec, blocks: dict | None = None, H: float | None = None) -> np.ndarray:
    """One-step map S_{n+1} = T S_n of the linearised co-simulation, S = [theta, omega of every node,
    the torque output of every connection's spring side]."""
    from scipy.linalg import expm

    blocks = blocks or blocks_from_spec(spec)
    H = float(H or spec.comm_step)
    offs, n = {}, 0
    for name, b in blocks.items():
        offs[name] = n
        n += b.n
    conns = []
    for conn in spec.connections:
        sc, sp = conn.spring.split(".", 1)
        ic, ip = conn.inertia.split(".", 1)
        conns.append((sc, blocks[sc].port(sp), ic, blocks[ic].port(ip)))
    nc = len(conns)
    N = 2 * n + nc
    T = np.zeros((N, N))
    for name, b in blocks.items():
        o = offs[name]
        nb = b.n
        sp_ports = [(ci, c) for ci, c in enumerate(conns) if c[0] == name]
        in_ports = [(ci, c) for ci, c in enumerate(conns) if c[2] == name]
        ns = len(sp_ports)
        ni = len(in_ports)
        # z = [th(nb), om(nb), phi(ns), w(ns), tau(ni), I(ns)]
        nz = 2 * nb + 2 * ns + ni + ns
        A = np.zeros((nz, nz))
        Mi = np.linalg.inv(b.M)
        Kb = b.K + (b.K_ground if b.K_ground is not None else 0.0)
        Cb = b.C + (b.C_ground if b.C_ground is not None else 0.0)
        Kt = Kb.copy()
        Ct = Cb.copy()
        F = np.zeros((nb, nz))            # generalized force contributions from inputs
        for s_, (ci, (sc, ps, ic, pi)) in enumerate(sp_ports):
            j, r = ps.node, ps.ratio
            Kt[j, j] += ps.k * r * r
            Ct[j, j] += ps.c * r * r
            F[j, 2 * nb + s_] += ps.k * r            # phi
            F[j, 2 * nb + ns + s_] += ps.c * r       # w
        for i_, (ci, (sc, ps, ic, pi)) in enumerate(in_ports):
            F[pi.node, 2 * nb + 2 * ns + i_] += pi.ratio
        A[:nb, nb:2 * nb] = np.eye(nb)
        A[nb:2 * nb, :nb] = -Mi @ Kt
        A[nb:2 * nb, nb:2 * nb] = -Mi @ Ct
        A[nb:2 * nb, :] += Mi @ F
        for s_ in range(ns):
            A[2 * nb + s_, 2 * nb + ns + s_] = 1.0           # phi' = w
        for s_, (ci, (sc, ps, ic, pi)) in enumerate(sp_ports):
            j, r = ps.node, ps.ratio
            row = 2 * nb + 2 * ns + ni + s_
            A[row, j] += ps.k * r
            A[row, nb + j] += ps.c * r
            A[row, 2 * nb + s_] -= ps.k
            A[row, 2 * nb + ns + s_] -= ps.c
        E = expm(A * H)
        # z0 as a function of the global state S
        Z0 = np.zeros((nz, N))
        Z0[:nb, o:o + nb] = np.eye(nb)
        Z0[nb:2 * nb, n + o:n + o + nb] = np.eye(nb)
        for s_, (ci, (sc, ps, ic, pi)) in enumerate(sp_ports):
            q = offs[ic] + pi.node
            Z0[2 * nb + s_, q] = pi.ratio
            Z0[2 * nb + ns + s_, n + q] = pi.ratio
        for i_, (ci, c) in enumerate(in_ports):
            Z0[2 * nb + 2 * ns + i_, 2 * n + ci] = 1.0
        Z1 = E @ Z0
        T[o:o + nb, :] = Z1[:nb]
        T[n + o:n + o + nb, :] = Z1[nb:2 * nb]
        dZ1 = A @ Z1
        for s_, (ci, (sc, ps, ic, pi)) in enumerate(sp_ports):
            j, r = ps.node, ps.ratio
            defl = r * Z1[j] - Z1[2 * nb + s_]
            rel = r * Z1[nb + j] - Z1[2 * nb + ns + s_]
            tend = ps.k * defl + ps.c * rel
            out = b.output_torque
            if out == "mean":
                T[2 * n + ci, :] = Z1[2 * nb + 2 * ns + ni + s_] / H
            elif out == "end":
                T[2 * n + ci, :] = tend
            else:
                rate = ps.k * rel + ps.c * r * dZ1[nb + j]
                T[2 * n + ci, :] = tend + 0.5 * H * rate
    return T


def cosim_radius(spec: SystemSpec, blocks: dict | None = None, H: float | None = None) -> float:
    """Spectral radius of the one-step map of the linearised co-simulation (an eigenvalue exactly 1,
    the free rotation angle when nothing grounds the chain, is excluded)."""
    T = cosim_map(spec, blocks, H)
    ev = np.linalg.eigvals(T)
    mag = np.abs(ev)
    i1 = int(np.argmin(np.abs(ev - 1.0)))
    if abs(ev[i1] - 1.0) < 1e-8:
        mag = np.delete(mag, i1)
    return float(mag.max())


# ------------------------------------------------------------------------------------------------
# CLI
# ------------------------------------------------------------------------------------------------

def _mode_damping(f: np.ndarray, V: np.ndarray, ls, fd: np.ndarray, zeta: np.ndarray) -> list[tuple[float, bool]]:
    """(damping ratio, overdamped) of every undamped mode. The modal projection ``x'Cx / (2 w x'Mx)`` says
    whether the mode oscillates at all: >= 1 is overdamped (its state-space eigenvalues are real: no
    frequency, no oscillation), reported with that ratio. An oscillating mode takes the exact ratio of
    the complex eigenvalue nearest in frequency (each eigenvalue given to one mode only, within 25 %),
    else the projection's."""
    out: list[tuple[float, bool]] = []
    free = list(range(len(fd)))
    for m in range(len(f)):
        x, w = V[:, m], 2.0 * math.pi * f[m]
        z_proj = float(x @ ls.C @ x / (2.0 * w * (x @ ls.M @ x)))
        if z_proj >= 1.0:
            out.append((z_proj, True))
            continue
        near = [j for j in free if abs(fd[j] / f[m] - 1.0) < 0.25]
        if near:
            j = min(near, key=lambda j: abs(fd[j] / f[m] - 1.0))
            free.remove(j)
            out.append((float(zeta[j]), False))
        else:
            out.append((z_proj, False))
    return out


def describe_modes(spec: SystemSpec, n_modes: int = 10, gear: str = "auto") -> list[dict]:
    """Per mode: the undamped natural frequency ``f_Hz``, the damping ratio ``zeta`` of the damped system
    (shafts', mesh's and cuts' damping; PI controller and losses excluded) and ``overdamped`` (zeta >= 1:
    the mode does not oscillate), the dominant strain (which spring) and kinetic energy (which node)."""
    f, V, ls, fd, zeta = modes(spec, gear, controller=False, damped=True)
    K, M = ls.K, ls.M
    blocks = blocks_from_spec(spec, gear, operating=False)
    # springs: internal elements (off-diagonal K) + connections
    springs = []
    offs, n = {}, 0
    for name, b in blocks.items():
        offs[name] = n
        for i in range(b.n - 1):
            if b.K[i, i + 1] != 0:
                lbl = f"{name}: {b.node_names[i]}-{b.node_names[i + 1]}"
                v = np.zeros(ls.M.shape[0])
                ki = -b.K[i, i + 1]
                if b.model == GEAR_MODEL:
                    v[n + i], v[n + i + 1] = 1.0, b.K[0, 1] / b.K[0, 0]
                    ki = b.K[0, 0]
                    lbl = f"{name}: mesh"
                else:
                    v[n + i], v[n + i + 1] = 1.0, -1.0
                springs.append((lbl, ki, v))
        n += b.n
    for conn in spec.connections:
        sc, sp = conn.spring.split(".", 1)
        ic, ip = conn.inertia.split(".", 1)
        ps, pi = blocks[sc].port(sp), blocks[ic].port(ip)
        v = np.zeros(ls.M.shape[0])
        v[offs[sc] + ps.node] += ps.ratio
        v[offs[ic] + pi.node] -= pi.ratio
        springs.append((f"cut {conn.spring}->{conn.inertia}", ps.k, v))
    out = []
    damping = _mode_damping(f, V, ls, fd, zeta)
    for m in range(min(n_modes, len(f))):
        x = V[:, m]
        se = np.array([kk * (v @ x) ** 2 for _, kk, v in springs])
        ke = np.diag(M) * x ** 2
        si = int(np.argmax(se))
        ki = int(np.argmax(ke))
        zm, over = damping[m]
        out.append({"mode": m + 1, "f_Hz": float(f[m]), "zeta": zm, "overdamped": over,
                    "strain": springs[si][0], "strain_share": float(se[si] / se.sum()),
                    "kinetic": ls.labels[ki], "kinetic_share": float(ke[ki] / ke.sum())})
    return out


# ------------------------------------------------------------------------------------------------
# The modes of a lumped table itself (any chain: the rig's or another machine's, unpartitioned)
# ------------------------------------------------------------------------------------------------

def chain_modes(model: PublicModel, n_modes: int | None = None) -> list[dict]:
    """The modes of a lumped torsional chain (``drivetrain.rig.data.PublicModel``: a table's nodes and elements,
    as read by ``load_public``), referred to its first node, free-free (the rigid-body mode removed), every mesh
    and gear rigid at its ratio: per mode the undamped natural frequency ``f_Hz``, the damping ratio ``zeta``
    of the table's dampings (projected on the undamped mode: ``c_m / (2 w_m)``, mass-normalised), the node of
    the largest kinetic energy ``kinetic_node`` (1-based) and its share, the element of the largest strain
    energy ``strain_element`` and its share."""
    from scipy.linalg import eigh

    M, K, C = public_matrices(model)
    w2, V = eigh(K, M)                      # mass-normalised: V.T M V = I
    keep = w2 > (2 * math.pi * 0.05) ** 2
    w2, V = w2[keep], V[:, keep]
    R2 = model.R[1:] ** 2
    out = []
    for m in range(len(w2) if n_modes is None else min(n_modes, len(w2))):
        x = V[:, m]
        wn = math.sqrt(w2[m])
        ke = np.diag(M) * x ** 2
        se = np.asarray(model.k) * R2 * np.diff(x) ** 2
        out.append({"mode": m + 1, "f_Hz": wn / (2 * math.pi), "zeta": float(x @ C @ x) / (2 * wn),
                    "kinetic_node": int(np.argmax(ke)) + 1, "kinetic_share": float(ke.max() / ke.sum()),
                    "strain_element": int(np.argmax(se)) + 1, "strain_share": float(se.max() / se.sum())})
    return out
