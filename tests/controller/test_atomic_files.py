"""Outputs appear whole or not at all: a write failing or interrupted halfway leaves the file that
was there before, and nothing beside it."""
import os
from pathlib import Path

import pytest

from controller.atomic_files import PendingFile, replace_atomically, write_text_atomically
from controller.errors import BadInput
from controller.plotting import pyplot, save_figure


def _half_then(exc):
    def write(tmp):
        Path(tmp).write_text('{"P1": [[1, 0')       # half a file, then the failure
        raise exc
    return write


@pytest.mark.parametrize("exc, raised", [(OSError(28, "No space left on device"), BadInput),
                                         (KeyboardInterrupt(), KeyboardInterrupt)])
def test_a_write_failing_halfway_leaves_the_old_file_and_nothing_else(tmp_path, exc, raised):
    out = tmp_path / "CALIB.json"
    out.write_text("the calibration before")
    with pytest.raises(raised) as got:
        replace_atomically(out, _half_then(exc))
    if raised is BadInput:
        assert str(got.value) == f"{out}: cannot write: No space left on device"
    assert out.read_text() == "the calibration before"
    assert [p.name for p in tmp_path.iterdir()] == ["CALIB.json"]


def test_a_new_file_has_the_users_umask_and_its_directory_is_made(tmp_path):
    old = os.umask(0o027)
    try:
        write_text_atomically(tmp_path / "new" / "x.json", "{}\n")
        (tmp_path / "plain.json").write_text("{}\n")
    finally:
        os.umask(old)
    assert (tmp_path / "new" / "x.json").read_text() == "{}\n"
    assert (tmp_path / "new" / "x.json").stat().st_mode == (tmp_path / "plain.json").stat().st_mode
    assert [p.name for p in (tmp_path / "new").iterdir()] == ["x.json"]


@pytest.mark.parametrize("name, magic", [("hist.png", b"\x89PNG"), ("hist.pdf", b"%PDF"), ("hist", b"\x89PNG")])
def test_a_figure_is_written_in_the_format_its_name_asks_for(tmp_path, name, magic):
    fig = pyplot().figure()
    save_figure(fig, str(tmp_path / name))
    assert (tmp_path / name).read_bytes().startswith(magic)
    assert [p.name for p in tmp_path.iterdir()] == [name]


def test_a_file_replaced_keeps_its_permissions(tmp_path):
    out = tmp_path / "CALIB.json"
    out.write_text("before")
    out.chmod(0o600)
    write_text_atomically(out, "after")
    assert out.read_text() == "after" and out.stat().st_mode & 0o777 == 0o600


def test_a_pending_file_takes_its_name_on_commit_only_keeping_the_old_ones_permissions(tmp_path):
    out = tmp_path / "FISH.csv"
    out.write_text("last week's fish")
    out.chmod(0o640)
    pending = PendingFile(out, "the CSV")
    pending.file.write("frame,length_cm\n")
    assert out.read_text() == "last week's fish"           # a reader sees the old file until the end
    pending.commit()
    pending.commit()
    pending.discard()                                       # (after a commit: nothing to undo)
    assert out.read_text() == "frame,length_cm\n" and out.stat().st_mode & 0o777 == 0o640
    assert [p.name for p in tmp_path.iterdir()] == ["FISH.csv"]


def test_a_pending_file_discarded_leaves_the_old_file_and_nothing_beside_it(tmp_path):
    out = tmp_path / "new" / "OUT.json"
    out.parent.mkdir()
    out.write_text("before")
    pending = PendingFile(out, "OUT.json")
    pending.file.write('{"fish": [')
    pending.discard()
    pending.discard()
    assert out.read_text() == "before" and [p.name for p in out.parent.iterdir()] == ["OUT.json"]


def test_a_pending_file_where_none_can_be_written_is_refused_at_once(tmp_path):
    (tmp_path / "file").write_text("")
    with pytest.raises(BadInput) as got:
        PendingFile(tmp_path / "file" / "OUT.json", "OUT.json")
    assert str(got.value).startswith(f"{tmp_path / 'file' / 'OUT.json'}: cannot write OUT.json: ")


def _fifo_reader(path: Path):
    """A reader on the FIFO ``path`` in a thread: returns a function giving what it read."""
    import threading
    got: list[bytes] = []
    thread = threading.Thread(target=lambda: got.append(path.read_bytes()), daemon=True)
    thread.start()

    def read() -> bytes:
        thread.join(10)
        return got[0] if got else b"(nothing read)"
    return read


def test_a_fifo_is_written_into_not_replaced(tmp_path):
    """``--json myfifo`` (or /dev/null, /dev/stdout) was renamed over: a plain file stood where the
    pipe or the system's device had been, and the reader got nothing."""
    fifo = tmp_path / "out.json"
    os.mkfifo(fifo)
    read = _fifo_reader(fifo)
    write_text_atomically(fifo, '{"count": 0}')
    assert read() == b'{"count": 0}'
    assert fifo.is_fifo() and [p.name for p in tmp_path.iterdir()] == ["out.json"]


def test_a_pending_file_on_a_fifo_is_written_into_on_commit(tmp_path):
    fifo = tmp_path / "FISH.csv"
    os.mkfifo(fifo)
    pending = PendingFile(fifo, "the fish")
    pending.file.write("fish,length_cm\n1,20.5\n")
    read = _fifo_reader(fifo)
    pending.commit()
    pending.commit()                                # twice is safe
    assert read() == b"fish,length_cm\n1,20.5\n" and fifo.is_fifo()
    pending.discard()
    assert [p.name for p in tmp_path.iterdir()] == ["FISH.csv"]


def test_a_link_keeps_pointing_where_it_did_and_its_file_is_replaced(tmp_path):
    (tmp_path / "real").mkdir()
    target = tmp_path / "real" / "CALIB.json"
    target.write_text("old")
    link = tmp_path / "CALIB.json"
    link.symlink_to(target)
    write_text_atomically(link, "new")
    assert link.is_symlink() and target.read_text() == "new"
    pending = PendingFile(link, "the survey")
    pending.file.write("newer")
    pending.commit()
    assert link.is_symlink() and target.read_text() == "newer"
    assert sorted(p.name for p in (tmp_path / "real").iterdir()) == ["CALIB.json"]


def test_outputs_into_a_fifo_are_neither_refused_nor_one_file_twice(tmp_path):
    from controller.cli.output_paths import check_outputs
    fifo = tmp_path / "sink"
    os.mkfifo(fifo)
    check_outputs({"--json": str(fifo), "--csv": str(fifo)}, [])


def _dead_pid() -> int:
    """A process id that was a process's and is no longer (reaped)."""
    import subprocess
    import sys
    child = subprocess.Popen([sys.executable, "-c", "pass"])
    child.wait()
    return child.pid


@pytest.mark.parametrize("writer", ["pending", "replace"])
def test_parts_left_by_writers_killed_outright_are_swept_by_the_next_writer_of_the_name(tmp_path, writer):
    """A survey SIGKILLed leaves its .part (nothing of it runs after the kill): the next one writing
    that name sweeps it, and only the parts of writers that are gone, of that name."""
    import subprocess
    import sys
    out = tmp_path / "o.json"
    dead = [_dead_pid() for _ in range(2)]
    live = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        gone = [tmp_path / f".o.json.{pid}.part" for pid in dead]
        kept = [tmp_path / f".o.json.{live.pid}.part", tmp_path / ".o.json.x1.part",
                tmp_path / f".other.json.{dead[0]}.part", tmp_path / f".o.json.{dead[0]}.part.bak"]
        for p in gone + kept:
            p.write_text("half")
        if writer == "pending":
            pending = PendingFile(out, "the survey")
            pending.file.write("{}")
            pending.commit()
        else:
            write_text_atomically(out, "{}")
        assert out.read_text() == "{}"
        assert not any(p.exists() for p in gone) and all(p.exists() for p in kept)
    finally:
        live.kill()
        live.wait()


_WRITER = """
import sys
from controller.atomic_files import PendingFile, replace_atomically, write_text_atomically
kind, name = sys.argv[1], sys.argv[2]
print("printed first", flush=True)
if kind == "text":
    write_text_atomically(name, '{"count": 0}\\n')
elif kind == "bytes":
    replace_atomically(name, lambda tmp: open(tmp, "wb").write(b"\\x89PNG\\r\\n"))
else:
    pending = PendingFile(name, "the fish")
    pending.file.write("fish,length_cm\\n")
    pending.commit()
    pending.commit()
"""


@pytest.mark.parametrize("name", ["-", "/dev/stdout", "/dev/fd/1", "/proc/self/fd/1"])
@pytest.mark.parametrize("kind, data", [("text", b'{"count": 0}\n'), ("bytes", b"\x89PNG\r\n"),
                                        ("pending", b"fish,length_cm\n")])
def test_the_standard_output_sent_to_a_log_is_appended_to_not_replaced(tmp_path, name, kind, data):
    """``--out - >> calibrations.log`` truncated the log (the name was opened for writing) or renamed
    a new file over it; what the command printed before and after went to the old file, lost."""
    import subprocess
    import sys
    log = tmp_path / "calibrations.log"
    log.write_bytes(b"yesterday's calibration\n")
    with open(log, "ab") as out:
        done = subprocess.run([sys.executable, "-c", _WRITER, kind, name], stdout=out, stderr=subprocess.PIPE,
                              cwd=Path(__file__).resolve().parents[2], timeout=60)
    assert done.returncode == 0, done.stderr
    assert log.read_bytes() == b"yesterday's calibration\nprinted first\n" + data
    assert [p.name for p in tmp_path.iterdir()] == ["calibrations.log"]


def test_the_standard_output_in_a_pipe_gets_the_data_after_what_was_printed(capsys):
    print("printed first")
    write_text_atomically("-", "data\n")
    pending = PendingFile("-", "the fish")
    pending.file.write("more\n")
    pending.discard()                              # discarded: nothing written
    assert capsys.readouterr().out == "printed first\ndata\n"
