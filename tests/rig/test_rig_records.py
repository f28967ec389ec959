"""The rig records' reader (drivetrain.rig.record.load_record / read_columns): the shipped records load, and a bad
record is refused with an error naming the file and the problem."""
import shutil
from pathlib import Path

import numpy as np
import pytest

from drivetrain.rig import record as rec

SHIPPED = rec.RECORD_DIR


@pytest.mark.parametrize("name", list(rec.RECORDS))
def test_every_shipped_record_loads_at_its_operating_point(name):
    r = rec.load_record(name=name)
    spec = rec.RECORDS[name]
    cut = int(0.2 * r.fs)
    w = np.mean(r.channels["enc1_w"][cut:])
    assert w == pytest.approx(spec.speed_rpm * np.pi / 30.0, rel=0.01)
    # the load motor's torque (the excitation files give it x8, at the propeller shaft): within its 11.9 N·m rating
    assert 0.0 < np.median(r.motor["load_motor_torque"]) < 11.9 / 4


def _copy(tmp_path, name="impulse_2004rpm"):
    for f in (rec.RECORDS[name].sensor_csv, rec.RECORDS[name].motor_csv):
        shutil.copy(SHIPPED / f, tmp_path / f)
    return tmp_path / rec.RECORDS[name].sensor_csv


def _lines(path: Path) -> list[str]:
    return path.read_text().splitlines()


@pytest.mark.parametrize("mutate, expected", [
    (lambda ls: [], "empty record"),
    (lambda ls: ls[:1], "a single row"),
    (lambda ls: ls[:5] + [ls[5] + ",1.0"] + ls[6:], "line 6 has 6 columns, 5 expected"),
    (lambda ls: ls[:5] + [",".join(ls[5].split(",")[:4])] + ls[6:], "line 6 has 4 columns"),
    (lambda ls: ls[:7] + [ls[7].rsplit(",", 1)[0] + ",nan"] + ls[8:], "line 8: a non-finite value"),
    (lambda ls: ls[:7] + [ls[7].rsplit(",", 1)[0] + ",inf"] + ls[8:], "line 8: a non-finite value"),
    (lambda ls: ls[:7] + [ls[7].rsplit(",", 1)[0] + ",abc"] + ls[8:], "line 8: not a number"),
    (lambda ls: ls[:3] + [ls[2]] + ls[3:], "time does not increase at line 4"),
])
def test_a_bad_record_is_refused_naming_file_and_problem(tmp_path, mutate, expected):
    sensor = _copy(tmp_path)
    sensor.write_text("\n".join(mutate(_lines(sensor))) + "\n")
    with pytest.raises(rec.RecordError) as ei:
        rec.load_record(tmp_path, "impulse_2004rpm")
    assert str(sensor) in str(ei.value) and expected in str(ei.value), str(ei.value)


def test_a_missing_record_file_and_an_unknown_record_are_refused(tmp_path):
    with pytest.raises(rec.RecordError, match="no such record file"):
        rec.load_record(tmp_path, "sine_2004rpm")
    with pytest.raises(rec.RecordError, match="unknown record"):
        rec.load_record(None, "sine_9000rpm")
