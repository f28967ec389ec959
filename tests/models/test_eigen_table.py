"""The modes of another machine (issue 42, item 2): a lumped table's own chain (models.eigen.chain_modes) and
the assembled drivetrain of a scene that names it, against oracles that do not use either: the closed form of
a two-inertia machine (plain and geared), and the scaling law (every inertia x4 -> every frequency / 2)."""
import math
from pathlib import Path

import numpy as np
import pytest

from drivetrain.models import eigen
from drivetrain.rig import data as rig
from drivetrain.rig.lumped_table import COLUMNS
from drivetrain.run.assemble import assemble
from drivetrain.scene.load import scene_from_dict

ROOT = Path(__file__).resolve().parents[2]
TWO_MASS = ROOT / "scenarios" / "other_gearboxes" / "two_mass_machine.csv"


def _table(path, rows):
    path.write_text(",".join(COLUMNS) + "\n" + "\n".join(",".join(map(str, r)) for r in rows) + "\n")
    return path


def _rig_scaled(tmp_path, factor_J: float):
    """The rig's table with every inertia times ``factor_J`` (its text otherwise as shipped)."""
    out = []
    for ln in rig.PUBLIC_CSV.read_text().splitlines():
        if ln and not ln.startswith("#") and not ln.startswith("node"):
            f = ln.split(",")
            f[1] = repr(float(f[1]) * factor_J)
            ln = ",".join(f)
        out.append(ln)
    p = tmp_path / f"rig_J_x{factor_J:g}.csv"
    p.write_text("\n".join(out) + "\n")
    return p


def test_two_inertia_machine_against_the_closed_form(tmp_path):
    """f = (1/2 pi) sqrt(k (J1 + J2) / (J1 J2)): the shipped example and a stiffer, lighter one."""
    f = [r["f_Hz"] for r in eigen.chain_modes(rig.load_public(TWO_MASS))]
    assert len(f) == 1
    assert f[0] == pytest.approx(math.sqrt(2000.0 * 0.06 / (0.02 * 0.04)) / (2 * math.pi), rel=1e-12)
    assert f[0] == pytest.approx(61.640, abs=1e-3)                 # the figure its comment states
    J1, J2, k = 3.5e-4, 1.2e-3, 4.5e4
    f = eigen.chain_modes(rig.load_public(_table(tmp_path / "m.csv", [(1, J1, 0, k, 0, 1), (2, J2, 0, "", "", "")])))
    assert f[0]["f_Hz"] == pytest.approx(math.sqrt(k * (J1 + J2) / (J1 * J2)) / (2 * math.pi), rel=1e-12)


def test_geared_two_inertia_machine_takes_the_stiffness_in_the_frame_of_the_next_node(tmp_path):
    """Element 1 geared at r = speed(2)/speed(1): its stiffness acts in node 2's frame (the convention of the
    table, rig.data): referred to node 1, k r^2 and J2 r^2, so f = (1/2 pi) sqrt(k r^2 (J1 + J2 r^2) / (J1 J2 r^2))
    = (1/2 pi) sqrt(k (J1 + J2 r^2) / (J1 J2))."""
    J1, J2, k, r = 2e-3, 5e-2, 8e3, 0.25
    p = _table(tmp_path / "geared.csv", [(1, J1, 0, k, 0, r), (2, J2, 0, "", "", "")])
    f = eigen.chain_modes(rig.load_public(p))[0]["f_Hz"]
    assert f == pytest.approx(math.sqrt(k * (J1 + J2 * r * r) / (J1 * J2)) / (2 * math.pi), rel=1e-12)


def test_every_inertia_x4_halves_every_mode_of_the_table(tmp_path):
    base = np.array([r["f_Hz"] for r in eigen.chain_modes(rig.load_public())])
    heavy = np.array([r["f_Hz"] for r in eigen.chain_modes(rig.load_public(_rig_scaled(tmp_path, 4.0)))])
    assert len(base) == len(heavy) == 21
    np.testing.assert_allclose(heavy, base / 2, rtol=1e-9)
    np.testing.assert_allclose(base[:3], [27.9, 39.6, 68.2], atol=0.06)     # the published model's modes


def test_every_inertia_x4_halves_every_mode_of_the_assembled_drivetrain(tmp_path):
    """The scene that names the heavier table, assembled into the four FMUs' parameters (lumping, partition,
    cuts): every undamped mode halves, with a rigid mesh and with the ISO 6336 mesh stiffness (not from the
    table: it stays, and the inertias against it are 4 times as large)."""
    def freqs(table, mesh):
        raw = {"effects": {"mesh_contact": mesh}}
        if table is not None:
            raw["drivetrain"] = {"parameters": str(table)}
        return eigen.natural_frequencies(assemble(scene_from_dict(raw), check=False))

    heavy = _rig_scaled(tmp_path, 4.0)
    for mesh in ("ideal", "table"):
        f0, f4 = freqs(None, mesh), freqs(heavy, mesh)
        assert len(f0) == len(f4) > 8
        np.testing.assert_allclose(f4, f0 / 2, rtol=1e-9, err_msg=mesh)
    assert freqs(None, "table")[0] == pytest.approx(24.0, abs=0.05)        # the rig's calibrated first mode


def test_drivetrain_eigen_reports_a_table_and_a_scene_naming_one(capsys, tmp_path):
    from drivetrain.cli import main

    assert main(["eigen", "--parameters", str(TWO_MASS)]) == 0
    out = capsys.readouterr().out
    assert "61.64" in out and str(TWO_MASS) in out
    scene = ROOT / "scenarios" / "other_gearboxes" / "heavy_propeller_machine.toml"
    assert main(["eigen", str(scene), "--modes", "4"]) == 0
    out = capsys.readouterr().out
    assert "modes of the lumped table" in out and "natural frequencies of heavy_propeller_machine" in out
    bad = _table(tmp_path / "bad.csv", [(1, -1, 0, 10, 0, 1), (2, 1, 0, "", "", "")])
    assert main(["eigen", "--parameters", str(bad)]) == 2
    err = capsys.readouterr().err
    assert str(bad) in err and "J_kgm2 = '-1'" in err


def test_another_chain_assembled_has_the_modes_of_its_table_with_rigid_gears(tmp_path):
    """A 7-node machine outside the rig's layout (every place its own node: nothing condensed), assembled into the
    FMUs' parameters with rigid shafts and the ideal (rigid) mesh: its modes are those of the table's chain with
    the upper gearbox and the mesh rigid, built here by hand from the table (referred to the motor: J R^2, a geared
    element's k in its output node's frame)."""
    from scipy.linalg import eigh

    J = [0.01, 0.02, 0.025, 0.004, 0.0008, 0.006, 0.5]
    k = [4000.0, 6000.0, 2e5, 12000.0, 1e6, 9000.0]
    ratio = [1, 1, 0.5, 1, 0.25, 1]
    table = _table(tmp_path / "seven.csv", [(i + 1, J[i], 0, k[i] if i < 6 else "", 0.1 if i < 6 else "",
                                             ratio[i] if i < 6 else "") for i in range(7)])
    ru, rp = 0.5, 0.5 * 0.25
    M = np.diag([J[0], J[1], J[2] + J[3] * ru ** 2, J[4] * ru ** 2 + J[5] * rp ** 2, J[6] * rp ** 2])
    springs = [(0, 1, k[0]), (1, 2, k[1]), (2, 3, k[3] * ru ** 2), (3, 4, k[5] * rp ** 2)]
    K = np.zeros((5, 5))
    for a, b, kk in springs:
        K[a, a] += kk
        K[b, b] += kk
        K[a, b] -= kk
        K[b, a] -= kk
    w2 = eigh(K, M, eigvals_only=True)
    oracle = np.sqrt(w2[1:]) / (2 * math.pi)
    scene = scene_from_dict({"drivetrain": {"parameters": str(table)},
                             "effects": {"mesh_contact": "ideal", "shaft_flexibility": "rigid"}})
    f = eigen.natural_frequencies(assemble(scene, check=False))
    np.testing.assert_allclose(f, oracle, rtol=1e-9)
    assert len(f) == 4
