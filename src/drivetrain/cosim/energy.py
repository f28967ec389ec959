"""The energy audit of a co-simulation run: does the work that entered balance what is stored and lost?

Every FMU reports ``energy_supplied``, ``energy_stored`` and ``energy_dissipated``; the audit adds the
work of external inputs at free ports and the energy held in the coupling (port springs) and returns
the relative residual of the balance (docs/MASTER.md, "Energy audit").
"""
from __future__ import annotations

import numpy as np

from drivetrain.fmu_build.fmus import ENERGY_VARS
from drivetrain.cosim.plan import ExchangePlan

#: smallest reference energy of the audit's relative residual [J]: 1 mJ, ~1e-5 of what the rig stores at speed (~100 J)
ENERGY_FLOOR_J = 1e-3


def energy_unavailable(reason: str) -> dict:
    """The energy audit of a run that has none (a failed run): same keys, no numbers."""
    return {"available": False, "reason": reason, "complete": False, "missing": [], "residual_J": None,
            "reference_J": None, "relative_residual": None, "supplied_J": None, "stored_change_J": None,
            "dissipated_J": None, "external_work_J": None, "worst_fmu": None, "per_fmu": {},
            "connections": [], "external": []}


def energy_audit(plan: ExchangePlan, rec: np.ndarray, e0: list[dict], e1: list[dict]) -> dict:
    """Energy balance of the run.

    Work through connection c (from the spring-side FMU into the inertia-side FMU), with the rule of the
    inertia side under a zero-order-held torque: W_c = Σ_k τ_k (φ_{k+1} − φ_k).
    Per FMU i: r_i = supplied_i + W_in,i − Δstored_i − dissipated_i; global residual
    R = Σ supplied + W_ext − Σ Δstored − Σ dissipated = Σ r_i (connection works cancel), where W_ext is the
    work of torques given as constant/profile inputs on unconnected inertia-side flanges (same rule).
    Reference energy: the largest of the absolute work through any connection or external flange
    ∫|P|dt and any FMU's |supplied|, at least ENERGY_FLOOR_J (a run that moves no energy, e.g. a
    drivetrain held at standstill, has no meaningful relative residual: measured 0/0 = 102 %).
    """
    n = len(plan.comps)
    conns = []
    w_in = np.zeros(n)
    ref = 0.0
    for (cs, ci, yt, yp, yw), in_spec in zip(plan.conn_index, _conn_specs(plan)):
        tau = rec[:-1, yt]
        dphi = np.diff(rec[:, yp])
        p = tau * dphi
        w = float(p.sum())
        wabs = float(np.abs(p).sum())
        w_in[ci] += w
        w_in[cs] -= w
        ref = max(ref, wabs)
        conns.append({"spring": in_spec[0], "inertia": in_spec[1], "work_J": w, "abs_work_J": wabs})
    external = []
    w_ext_tot = 0.0
    for ci, port, tau_c, yt, yp in plan.ext_work:
        dphi = np.diff(rec[:, yp])
        tau = tau_c if yt is None else rec[:-1, yt]
        p = tau * dphi
        w = float(np.sum(p))
        w_in[ci] += w
        w_ext_tot += w
        ref = max(ref, float(np.abs(p).sum()))
        external.append({"port": port, "work_J": w, "abs_work_J": float(np.abs(p).sum())})
    per = {}
    tot = {"supplied_J": 0.0, "stored_change_J": 0.0, "dissipated_J": 0.0}
    missing = []
    for i, c in enumerate(plan.comps):
        have = e1[i]
        if len(have) < len(ENERGY_VARS):
            missing.append(f"{c.name}: no " + ", ".join(e for e in ENERGY_VARS if e not in have))
        sup = have.get("energy_supplied", 0.0) - e0[i].get("energy_supplied", 0.0)
        dst = have.get("energy_stored", 0.0) - e0[i].get("energy_stored", 0.0)
        dis = have.get("energy_dissipated", 0.0) - e0[i].get("energy_dissipated", 0.0)
        r = sup + w_in[i] - dst - dis
        per[c.name] = {"supplied_J": sup, "stored_change_J": dst, "dissipated_J": dis,
                       "port_work_in_J": float(w_in[i]), "residual_J": float(r),
                       "stored_start_J": e0[i].get("energy_stored", float("nan")),
                       "stored_end_J": have.get("energy_stored", float("nan"))}
        tot["supplied_J"] += sup
        tot["stored_change_J"] += dst
        tot["dissipated_J"] += dis
        ref = max(ref, abs(sup))
    resid = tot["supplied_J"] + w_ext_tot - tot["stored_change_J"] - tot["dissipated_J"]
    return {
        "available": True, "complete": not missing, "missing": missing,
        "residual_J": resid, "reference_J": ref,
        "relative_residual": abs(resid) / max(ref, ENERGY_FLOOR_J),
        **tot, "external_work_J": w_ext_tot,
        "worst_fmu": max(per, key=lambda k: abs(per[k]["residual_J"])) if per else None,
        "per_fmu": per, "connections": conns, "external": external,
        "rule": "W_c = sum_k tau_k*(phi_{k+1}-phi_k) (tau held over each step, inertia-side angle); "
                "residual = supplied + external work - delta stored - dissipated over all FMUs; "
                "reference = max(max_c sum|P_c dt|, max_i |supplied_i|, external sum|P dt|, 1 mJ)",
    }


def _conn_specs(plan: ExchangePlan):
    out = []
    for cs, ci, yt, yp, yw in plan.conn_index:
        out.append((plan.y_names[yt].rsplit("_", 1)[0], plan.y_names[yp].rsplit("_", 1)[0]))
    return out
