"""Every command that writes a file refuses, before any work, an output that is a directory, another
of its outputs or one of its inputs: exit 2, one line naming the path, the option and the fault,
every input as it was and nothing written."""
import json
import os
import tomllib
from pathlib import Path

import pytest
import tomli_w

from controller.cli import main
from controller.cli.output_paths import check_outputs
from controller.errors import BadInput
from devices.sim.stereo_rig import convergent_rig

TOWER = '{"H": [[0.01, 0, 0], [0, 0.01, 0], [0, 0, 1]]}'


def _inputs(d: Path) -> dict[str, Path]:
    """The files the commands below read; contents only where a command reads them before its
    outputs are checked (the config, the tower camera's files, the survey's calibration)."""
    raw = tomllib.loads(Path("config/farm.toml").read_text())
    raw["store"] = {"path": str(d / "ledger.db")}
    calib = json.dumps(convergent_rig().calibration().to_json())
    files = {"farm.toml": tomli_w.dumps(raw), "tower.json": TOWER, "frames/frames.csv": "frame,t_s,file\n",
             "grid.csv": "x", "ref.csv": "x", "calib.json": calib, "pairs.csv": "x", "contacts.csv": "x",
             "stereo.yml": "x", "L1.png": "x", "R1.png": "x", "ledger.db": "x"}
    for name, text in files.items():
        (d / name).parent.mkdir(exist_ok=True)
        (d / name).write_text(text)
    return {name: d / name for name in files}


# command line with {out} for the output under test, the output's option, the inputs it may not name
COMMANDS = [
    ("calibrate dlt --points {grid.csv} --out {out}", "--out", ["grid.csv"]),
    ("calibrate dlt --points {grid.csv} --out c.json --report {out}", "--report", ["grid.csv"]),
    ("calibrate tower --points {ref.csv} --out {out}", "--out", ["ref.csv"]),
    ("calibrate chessboard --left {d}/L*.png --right {d}/R*.png --square-mm 25 --out {out}", "--out",
     ["L1.png", "R1.png"]),
    ("calibrate import --in {stereo.yml} --out {out}", "--out", ["stereo.yml"]),
    ("triangulate --calib {calib.json} --pairs {pairs.csv} --out {out}", "--out", ["calib.json", "pairs.csv"]),
    ("demand --events {contacts.csv} --config {farm.toml} --json {out}", "--json", ["contacts.csv", "farm.toml"]),
    ("track --frames {d}/frames --tower {tower.json} --json {out}", "--json", ["tower.json", "frames/frames.csv"]),
    ("report --tank T1 --config {farm.toml} --png {out}", "--png", ["farm.toml", "ledger.db"]),
    ("history --tank T1 --what surveys --config {farm.toml} --csv {out}", "--csv", ["farm.toml", "ledger.db"]),
    ("cleaner map --config {farm.toml} --png {out}", "--png", ["farm.toml", "ledger.db"]),
]


def _refused(capsys, d, line, out, *words):
    files = _inputs(d)
    before = {p: p.read_bytes() for p in files.values()}
    listing = sorted(d.rglob("*"))
    for name, path in {**files, "d": d, "out": out}.items():
        line = line.replace("{" + name + "}", str(path))
    rc = main(line.split())
    err = capsys.readouterr().err
    assert rc == 2, err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    for w in words:
        assert w in err, err
    assert {p: p.read_bytes() for p in files.values()} == before
    assert sorted(d.rglob("*")) == listing


@pytest.mark.parametrize("line, option, inputs", COMMANDS, ids=[c[0].split(" -")[0] + " " + c[1] for c in COMMANDS])
def test_an_output_naming_an_input_or_a_directory_is_refused_before_any_work(tmp_path, capsys, line, option, inputs):
    for name in inputs:
        # spelt another way than the input, so the paths are compared as files, not as strings
        _refused(capsys, tmp_path, line, tmp_path / "." / name, f"{name}: {option}: an input of this command")
        # and a hard link to it: another name, one file (an outside tester's calibration lost so)
        link = tmp_path / f"hardlink_{Path(name).name}"
        if not link.exists():
            os.link(tmp_path / name, link)
        _refused(capsys, tmp_path, line, link, f"{link.name}: {option}: an input of this command")
    # a directory that cannot be made: a file stands where it would be
    _refused(capsys, tmp_path, line, tmp_path / "ref.csv" / "out.x",
             f"out.x: {option}: cannot write: {tmp_path / 'ref.csv'} is a file, not a directory")
    # a directory that lets root past access() but takes no file (a --plot there failed after the survey)
    _refused(capsys, tmp_path, line, Path("/proc/out.x"),
             f"/proc/out.x: {option}: cannot write: /proc takes no new files")
    (tmp_path / "a_dir").mkdir()
    if "chessboard" in line or "import" in line:    # click's own check of the option (dir_okay=False)
        _refused(capsys, tmp_path, line, tmp_path / "a_dir", option, "a_dir", "directory")
    else:
        _refused(capsys, tmp_path, line, tmp_path / "a_dir", f"a_dir: {option}: a directory, not a file")


def test_two_outputs_naming_one_file(tmp_path, capsys):
    _refused(capsys, tmp_path, "calibrate dlt --points {grid.csv} --out {d}/c.json --report {out}",
             tmp_path / "." / "c.json", "c.json: --report: the same file as --out")
    (tmp_path / "c.json").write_text("{}")                      # an earlier run's, hard-linked
    os.link(tmp_path / "c.json", tmp_path / "report.json")
    _refused(capsys, tmp_path, "calibrate dlt --points {grid.csv} --out {d}/c.json --report {out}",
             tmp_path / "report.json", "report.json: --report: the same file as --out")


@pytest.mark.parametrize("line, option", [
    ("report --tank T1 --config {farm.toml} --png {out}", "--png"),
    ("cleaner map --config {farm.toml} --png {out}", "--png"),
    ("survey --calib {calib.json} --species sparus_aurata --setup underwater --pair {L1.png} {R1.png} "
     "--json {d}/out.json --plot {out}", "--plot"),
])
def test_a_picture_named_in_a_format_matplotlib_cannot_draw_is_refused_before_any_work(tmp_path, capsys, line,
                                                                                       option):
    _refused(capsys, tmp_path, line, tmp_path / "page.xyz", f"page.xyz: {option}: cannot draw a .xyz picture",
             "png", "svg")


def test_a_plot_where_no_file_can_be_made_is_refused_before_the_survey_and_its_json(tmp_path, capsys):
    _refused(capsys, tmp_path, "survey --calib {calib.json} --species sparus_aurata --setup underwater "
             "--pair {L1.png} {R1.png} --json {d}/out.json --plot {out}", Path("/proc/hist.png"),
             "/proc/hist.png: --plot: cannot write")


SERVERS = [("sim --config {farm.toml} --endpoints {out}", "--endpoints"),
           ("sim --config {farm.toml} --endpoints {d}/e.json --truth {out}", "--truth"),
           ("credentials --out {out}", "--out")]


@pytest.mark.parametrize("line, option", [(c[0], c[1]) for c in COMMANDS] + SERVERS,
                         ids=[c[0].split(" -")[0] + " " + c[1] for c in COMMANDS + SERVERS])
def test_an_empty_output_path_is_refused_naming_the_option(tmp_path, capsys, line, option):
    """An outside tester: ``--json ''`` crashed ("internal error: ... has an empty name", exit 1), and
    ``--png ''`` / ``--csv ''`` quietly wrote nothing or wrote to stdout."""
    files = _inputs(tmp_path)
    before = {p: p.read_bytes() for p in files.values()}
    listing = sorted(tmp_path.rglob("*"))
    args = []
    for word in line.split():
        for name, path in {**files, "d": tmp_path}.items():
            word = word.replace("{" + name + "}", str(path))
        args.append("" if word == "{out}" else word)
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{option}: '': an empty path" in err, err
    assert {p: p.read_bytes() for p in files.values()} == before and sorted(tmp_path.rglob("*")) == listing


@pytest.mark.parametrize("line, option", SERVERS, ids=[c[1] for c in SERVERS])
def test_the_simulator_s_and_the_credentials_files_where_none_can_be_made_are_refused(tmp_path, capsys, line,
                                                                                        option):
    """``sim --endpoints /proc/e.json`` and ``credentials --out /proc/c.txt``: "internal error:
    FileNotFoundError" (exit 1) once the work was done."""
    _refused(capsys, tmp_path, line, Path("/proc/out.x"),
             f"/proc/out.x: {option}: cannot write: /proc takes no new files")


@pytest.mark.parametrize("second", ["-", "/dev/stdout"])
def test_two_outputs_on_the_standard_output_are_refused(second):
    with pytest.raises(BadInput) as got:
        check_outputs({"--json": "-", "--csv": second}, [])
    assert str(got.value) == f"{second}: --csv: the standard output, as --json is: they would mix"
