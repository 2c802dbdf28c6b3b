"""CALIB.json read and written by the command line: the same one line, exit 2, as before vision/ gave up
its file I/O. Run in-process through ``fishfarm``'s own entry point (the subprocess runs are in
test_cli_calibrate_dlt.py)."""
import re

import pytest

from controller.cli import main
from controller.cli.calib_io import load_calibration, save_calibration
from controller.errors import BadInput
from tests.vision.calib_cases import CASES, FULL, message_pattern
from vision.calib_file import calibration_from_json


@pytest.mark.parametrize("case, text, message", CASES, ids=[c[0] for c in CASES])
def test_a_bad_calibration_file_is_one_line_naming_file_field_and_fault(case, text, message, tmp_path, capsys):
    calib = tmp_path / "CALIB.json"
    calib.write_text(text)
    pairs = tmp_path / "PAIRS.csv"
    pairs.write_text("u1,v1,u2,v2\n1,2,3,4\n")
    assert main(["triangulate", "--calib", str(calib), "--pairs", str(pairs)]) == 2
    err = capsys.readouterr().err
    assert re.fullmatch(re.escape(f"fishfarm: {calib}: ") + message_pattern(case, message) + "\n", err), err
    with pytest.raises(BadInput):
        load_calibration(calib)


def test_a_missing_calibration_file(tmp_path):
    with pytest.raises(BadInput) as err:
        load_calibration(tmp_path / "CALIB.json")
    assert str(err.value) == f"{tmp_path / 'CALIB.json'}: no such file"


def test_an_unwritable_calibration_file_names_it(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    with pytest.raises(BadInput) as err:
        save_calibration(calibration_from_json(FULL), blocker / "CALIB.json")
    assert str(err.value).startswith(f"{blocker / 'CALIB.json'}: cannot write: ")


def test_saved_then_loaded_is_the_same_calibration(tmp_path):
    calib = calibration_from_json(FULL)
    save_calibration(calib, tmp_path / "sub" / "CALIB.json")
    assert load_calibration(tmp_path / "sub" / "CALIB.json").to_json() == calib.to_json()


def test_a_calibration_saved_with_a_byte_order_mark_is_read(tmp_path):
    """Windows editors write one: refused as 'Unexpected UTF-8 BOM' (an outside tester), while the
    grid and DLT files with one were read."""
    import json
    plain = calibration_from_json(FULL)
    path = tmp_path / "CALIB.json"
    path.write_bytes(b"\xef\xbb\xbf" + json.dumps(FULL).encode())
    got = load_calibration(path)
    assert (got.P1 == plain.P1).all() and (got.P2 == plain.P2).all()
