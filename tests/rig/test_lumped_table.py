"""A machine's lumped torsional model from its table (issue 42, item 2): the checked reader
(drivetrain.rig.lumped_table) refuses each kind of bad table with the file, the row and what was wrong; the
rig's own table reads as before; the partition maps a table in the rig's layout and refuses one it cannot map."""
import numpy as np
import pytest

from drivetrain.errors import ConfigurationError, FileFormatError
from drivetrain.rig import data as rig
from drivetrain.rig.lumped_table import COLUMNS, read_lumped_table

HEADER = ",".join(COLUMNS)
GOOD = [HEADER, "1,0.02,0.001,2000,0.05,1", "2,0.01,0,500,0.02,1", "3,0.04,0.002,,,"]


def write(tmp_path, lines, name="machine.csv"):
    p = tmp_path / name
    p.write_text("\n".join(["# a comment line", *lines]) + "\n")
    return p


def refused(tmp_path, lines) -> str:
    p = write(tmp_path, lines)
    with pytest.raises(FileFormatError) as ei:
        read_lumped_table(p)
    text = str(ei.value)
    assert str(p) in text, text                  # every refusal names the file
    return text


def test_a_good_table_reads_in_any_column_order(tmp_path):
    t = read_lumped_table(write(tmp_path, GOOD))
    assert t["J"].tolist() == [0.02, 0.01, 0.04] and t["k"].tolist() == [2000.0, 500.0]
    assert t["c_ext"].tolist() == [0.001, 0.0, 0.002] and t["ratio"].tolist() == [1.0, 1.0]
    cols = list(reversed(COLUMNS))
    rows = [",".join(cols)] + [",".join(reversed(r.split(","))) for r in GOOD[1:]]
    t2 = read_lumped_table(write(tmp_path, rows, "reversed.csv"))
    assert all(np.array_equal(t[k], t2[k]) for k in t)


def test_the_rig_table_reads_as_the_plain_csv_parse():
    """The shipped table through the checked reader: every value the float of its text (the rig's partition
    is built from these, bit for bit)."""
    import csv

    rows = [r for r in csv.reader(open(rig.PUBLIC_CSV)) if r and not r[0].startswith("#")][1:]
    m = rig.load_public()
    assert m.J.tolist() == [float(r[1]) for r in rows]
    assert m.k.tolist() == [float(r[3]) for r in rows[:-1]]
    assert m.ratio.tolist() == [float(r[5]) for r in rows[:-1]]
    assert rig.layout_problems(m) == []


@pytest.mark.parametrize("lines, words", [
    # a missing column
    ([HEADER.replace(",c_ext_Nms_per_rad", ""), "1,0.02,2000,0.05,1", "2,0.04,,,"],
     "missing column(s) c_ext_Nms_per_rad"),
    # an unknown column (a misspelt one)
    ([HEADER.replace("J_kgm2", "J_kg_m2"), *GOOD[1:]], "unknown column(s) 'J_kg_m2'"),
    # a non-finite inertia
    ([HEADER, "1,nan,0,2000,0.05,1", "2,0.04,0,,,"], "line 3 (node 1): J_kgm2 = 'nan'; expected a finite inertia > 0"),
    ([HEADER, "1,inf,0,2000,0.05,1", "2,0.04,0,,,"], "J_kgm2 = 'inf'"),
    # a negative inertia
    ([HEADER, "1,0.02,0,2000,0.05,1", "2,-0.04,0,,,"], "line 4 (node 2): J_kgm2 = '-0.04'; expected a finite inertia > 0"),
    # a negative, a zero and a non-finite stiffness
    ([HEADER, "1,0.02,0,-2000,0.05,1", "2,0.04,0,,,"], "k_next_Nm_per_rad = '-2000'; expected a finite stiffness > 0"),
    ([HEADER, "1,0.02,0,0,0.05,1", "2,0.04,0,,,"], "k_next_Nm_per_rad = '0'"),
    ([HEADER, "1,0.02,0,1e999,0.05,1", "2,0.04,0,,,"], "k_next_Nm_per_rad = '1e999'"),
    # a missing stiffness inside the chain
    ([HEADER, "1,0.02,0,,0.05,1", "2,0.04,0,,,"], "k_next_Nm_per_rad is empty"),
    # a negative damping, a zero ratio, text where a number goes
    ([HEADER, "1,0.02,0,2000,-0.05,1", "2,0.04,0,,,"], "c_next_Nms_per_rad = '-0.05'; expected a finite damping >= 0"),
    ([HEADER, "1,0.02,0,2000,0.05,0", "2,0.04,0,,,"], "ratio_next = '0'; expected a finite speed ratio > 0"),
    ([HEADER, "1,0.02,0,2 kNm,0.05,1", "2,0.04,0,,,"], "k_next_Nm_per_rad = '2 kNm'"),
    # an unknown row: a node out of order, a node named twice, a node that is not a number
    ([HEADER, "1,0.02,0,2000,0.05,1", "3,0.04,0,,,"], "line 4: unknown row: node '3' where node 2 was expected"),
    ([HEADER, "1,0.02,0,2000,0.05,1", "1,0.04,0,,,"], "unknown row: node '1' where node 2 was expected"),
    ([HEADER, "1,0.02,0,2000,0.05,1", "motor,0.04,0,,,"], "unknown row: node 'motor'"),
    # a row of the wrong width, an element after the last node, a chain of one node
    ([HEADER, "1,0.02,0,2000,0.05", "2,0.04,0,,,"], "line 3 (node 1): 5 fields, the header has 6"),
    ([HEADER, "1,0.02,0,2000,0.05,1", "2,0.04,0,300,,"], "the last node has no next element; k_next_Nm_per_rad"),
    ([HEADER, "1,0.02,0,,,"], "1 node row(s); a torsional chain needs at least 2 nodes"),
])
def test_each_kind_of_bad_table_is_refused_naming_file_row_and_what(tmp_path, lines, words):
    assert words in refused(tmp_path, lines)


def test_every_problem_of_a_table_at_once(tmp_path):
    text = refused(tmp_path, [HEADER, "1,-1,0,2000,0.05,1", "2,0.04,0,-5,0.02,1", "3,0.04,0,,,"])
    assert "node 1): J_kgm2 = '-1'" in text and "node 2): k_next_Nm_per_rad = '-5'" in text


def test_not_a_text_file_nor_a_file(tmp_path):
    p = tmp_path / "binary.csv"
    p.write_bytes(b"\xff\xfe\x00\x01" * 10)
    with pytest.raises(FileFormatError, match="not a readable CSV text file"):
        read_lumped_table(p)
    with pytest.raises(FileFormatError, match="no such file"):
        read_lumped_table(tmp_path / "absent.csv")


def _rig_rows():
    return [ln for ln in rig.PUBLIC_CSV.read_text().splitlines() if ln and not ln.startswith("#")]


def test_the_partition_maps_a_table_of_the_rig_layout_and_refuses_another(tmp_path):
    """A table in the rig's 22-node layout partitions (its values reach the components); a two-mass chain (no
    bevel mesh) and a bevel element whose ratio is not the pair's z1/z2 are refused, before any component is built."""
    rows = _rig_rows()
    rows[22] = rows[22].replace("0.0495", "0.099")              # node 22: the propeller mass doubled
    m = rig.load_public(write(tmp_path, rows, "heavy.csv"))
    base, heavy = rig.partition(model=None), rig.partition(model=m)
    assert heavy.params["motors"]["J_load"] > base.params["motors"]["J_load"]
    # node 22 is all of the load body's own: +0.0495 kg m^2 (to the 1e-10 of the table's 10-digit ratio 1/3)
    assert heavy.params["motors"]["J_load"] - base.params["motors"]["J_load"] == pytest.approx(0.0495, rel=1e-9)
    assert heavy.params["upper"] == base.params["upper"] and heavy.params["drive_shaft"] == base.params["drive_shaft"]
    two = rig.load_public(write(tmp_path, GOOD[:2] + ["2,0.04,0.002,,,"], "two.csv"))
    with pytest.raises(ConfigurationError, match="the bevel mesh is the last geared element, its ratio_next the gear "
                                                 "pair's z1/z2 = 0.25; no element has ratio_next != 1"):
        rig.partition("rigid", model=two)
    rows = _rig_rows()
    rows[17] = rows[17].replace(",0.25", ",0.2")                # element 17: 1/5 but the pair is 15/60
    with pytest.raises(ConfigurationError, match=r"element 17 \(the bevel mesh\) has ratio_next = 0.2; the gear "
                                                 r"pair's z1/z2 = 0.25"):
        rig.partition(model=rig.load_public(write(tmp_path, rows, "odd.csv")))


def test_an_upper_gearbox_of_another_ratio_sets_the_frames(tmp_path):
    """Element 12 at 1/2 instead of 1/3: the upper transmission's ratio is 2, and every body and spring after
    it, given in its own frame (the middle and propeller shafts'), is the rig's: the same nodes and elements
    lumped the same way (to the 1e-10 of the rig table's 10-digit 1/3)."""
    rows = _rig_rows()
    rows[12] = rows[12].replace("0.3333333333", "0.5")
    part = rig.partition(model=rig.load_public(write(tmp_path, rows, "half.csv")))
    base = rig.partition()
    assert part.params["upper"]["ratio"] == 2.0 and base.params["upper"]["ratio"] == 3.0
    for name in ("J_pinion", "J_wheel", "k_a", "d_a", "k_b", "d_b"):
        assert part.params["gear"][name] == pytest.approx(base.params["gear"][name], rel=1e-9), name
    assert part.params["upper"]["J_out"] == pytest.approx(base.params["upper"]["J_out"], rel=1e-9)
    assert part.params["motors"]["J_load"] == pytest.approx(base.params["motors"]["J_load"], rel=1e-9)
    assert part.params["upper"]["J_in"] == pytest.approx(base.params["upper"]["J_in"], rel=1e-9)   # drive frame


def _chain(tmp_path, rows, name="chain.csv"):
    return rig.load_public(write(tmp_path, [HEADER, *(",".join(map(str, r)) for r in rows)], name))


#: a 7-node machine with every place of its own (nothing to condense): motor, flywheel, upper gearbox in/out
#: (element 3, 2:1), pinion, bevel mesh (element 5, 15/60), wheel, load
SEVEN = [(1, 0.01, 0.002, 4000, 0.4, 1), (2, 0.02, 0, 6000, 0.8, 1), (3, 0.025, 0, 2e5, 2, 0.5),
         (4, 0.004, 0, 12000, 0.3, 1), (5, 0.0008, 0, 1e6, 0, 0.25), (6, 0.006, 0, 9000, 0.2, 1), (7, 0.5, 0.1, "", "", "")]


def test_another_chain_finds_its_places_from_its_ratios(tmp_path):
    """A chain outside the rig's layout: the mesh is the last geared element (the pair's 15/60), the upper gearbox
    the geared element before it, the flywheel the heaviest node between the motor and the upper body; each
    component's parameter is its node's or element's, in its own frame (nothing condensed), the upper ratio 2."""
    m = _chain(tmp_path, SEVEN)
    places, problems = rig.chain_places(m)
    assert problems == [] and places == rig.Places(motor=1, flywheel=2, upper=3, upper_gear=3, mesh=5, pinion=5,
                                                   wheel=6, load=7)
    part = rig.partition("rigid", model=m, losses=False)
    mo, up, gear = part.params["motors"], part.params["upper"], part.params["gear"]
    assert (mo["J_motor"], mo["k_c1"], mo["d_c1"], mo["J_flywheel"], mo["k_c2"], mo["d_c2"], mo["J_load"]) == \
        (0.01, 4000.0, 0.4, 0.02, 6000.0, 0.8, 0.5)
    assert (up["J_in"], up["J_out"], up["ratio"]) == (0.025, 0.004, 2.0)
    assert (gear["J_pinion"], gear["J_wheel"], gear["k_a"], gear["k_b"]) == (0.0008, 0.006, 12000.0, 9000.0)
    assert part.calibration["coupling_scale"] == 1.0               # the rig's coupling factor is the rig's alone
    with pytest.raises(ConfigurationError, match="runs with rigid shafts"):
        rig.partition("flexible", model=m)


def test_another_chain_condenses_the_nodes_between_its_places(tmp_path):
    """Nodes between the places are condensed: springs in series (k = k1 k2 / (k1 + k2)), the inertia shared by
    the neighbours in proportion to the adjacent stiffnesses; the total inertia referred to the motor is kept."""
    rows = [(1, 0.01, 0.002, 4000, 0.4, 1), (2, 0.001, 0, 12000, 0.2, 1), (3, 0.02, 0, 6000, 0.8, 1),
            (4, 0.025, 0, 2e5, 2, 0.5), (5, 0.004, 0, 12000, 0.3, 1), (6, 0.0008, 0, 1e6, 0, 0.25),
            (7, 0.006, 0, 9000, 0.2, 1), (8, 0.002, 0, 18000, 0.1, 1), (9, 0.5, 0.1, "", "", "")]
    m = _chain(tmp_path, rows)
    part = rig.partition("rigid", model=m, losses=False)
    mo, gear = part.params["motors"], part.params["gear"]
    assert mo["k_c1"] == pytest.approx(4000 * 12000 / 16000, rel=1e-12)
    assert mo["J_motor"] == pytest.approx(0.01 + 0.001 * 4000 / 16000, rel=1e-12)
    assert mo["J_flywheel"] == pytest.approx(0.02 + 0.001 * 12000 / 16000, rel=1e-12)
    assert gear["k_b"] == pytest.approx(9000 * 18000 / 27000, rel=1e-12)
    assert mo["J_load"] + gear["J_wheel"] == pytest.approx(0.006 + 0.002 + 0.5, rel=1e-12)
    ref = m.J @ m.R ** 2
    lumped = (mo["J_motor"] + mo["J_flywheel"] + part.params["upper"]["J_in"] + part.params["upper"]["J_out"] / 4
              + (gear["J_pinion"] + gear["J_wheel"] / 16 + mo["J_load"] / 16) / 4)
    assert lumped == pytest.approx(ref, rel=1e-12)


@pytest.mark.parametrize("rows, words", [
    ([(1, 0.01, 0, 4000, 0, 1), (2, 0.02, 0, 6000, 0, 1), (3, 0.5, 0, "", "", "")], "no element has ratio_next != 1"),
    ([(1, 0.01, 0, 4000, 0, 1), (2, 0.02, 0, 6000, 0, 0.2), (3, 0.5, 0, 100, 0, 1), (4, 0.5, 0, "", "", "")],
     "element 2 has ratio_next = 0.2"),
    ([(1, 0.01, 0, 4000, 0, 0.5), (2, 0.02, 0, 6000, 0, 0.5), (3, 0.01, 0, 100, 0, 1), (4, 0.01, 0, 100, 0, 0.25),
      (5, 0.01, 0, 100, 0, 1), (6, 0.5, 0, "", "", "")], "elements 1, 2, 4 are geared: at most two"),
    ([(1, 0.01, 0, 4000, 0, 1), (2, 0.02, 0, 6000, 0, 0.25), (3, 0.01, 0, 100, 0, 1), (4, 0.5, 0, "", "", "")],
     "node 1 would be the upper gearbox's body"),
    ([(1, 0.01, 0, 4000, 0, 1), (2, 0.02, 0, 6000, 0, 1), (3, 0.01, 0, 100, 0, 0.5), (4, 0.01, 0, 100, 0, 0.25),
      (5, 0.01, 0, 100, 0, 1), (6, 0.5, 0, "", "", "")], "joins the bevel mesh's input node 4"),
    ([(1, 0.01, 0, 4000, 0, 1), (2, 0.02, 0, 6000, 0, 1), (3, 0.01, 0, 100, 0, 1), (4, 0.01, 0, 100, 0, 0.25),
      (5, 0.5, 0, "", "", "")], "the wheel (node 5) is the last node"),
])
def test_a_chain_without_the_places_is_refused_with_why(tmp_path, rows, words):
    problems = rig.layout_problems(_chain(tmp_path, rows))
    assert any(words in p for p in problems), problems
