"""The command line's error policy: a user's mistake is one line and exit 2, a bug keeps its traceback."""

from __future__ import annotations

import os
import stat

import pytest
from helpers import one_line_error

from hapticlab.sessions import cli
from hapticlab.sessions.cli import main


def test_a_missing_input_names_the_file(capsys, tmp_path):
    err = one_line_error(capsys, ["compensate", str(tmp_path / "nope.csv"), "-o", str(tmp_path / "out.csv")])
    assert err == f"hapticlab compensate: error: {tmp_path / 'nope.csv'}: no such file"


def test_a_file_that_is_not_mcap_names_the_file(capsys, tmp_path):
    bad = tmp_path / "notes.mcap"
    bad.write_text("these are my notes, not a recording\n")
    err = one_line_error(capsys, ["replay", str(bad), "--estimator", "rls"])
    assert err.startswith("hapticlab replay: error: ") and f"{bad} is not an MCAP file" in err


def test_an_output_that_is_a_folder_names_the_path(capsys, tmp_path):
    csv = tmp_path / "in.csv"
    csv.write_text(
        "t,fx,fy,fz,tx,ty,tz,qw,qx,qy,qz\n" + "".join(f"{k * 0.01},1,2,3,0.1,0.2,0.3,1,0,0,0\n" for k in range(30))
    )
    folder = tmp_path / "out"
    folder.mkdir()
    err = one_line_error(capsys, ["compensate", str(csv), "-o", str(folder)])
    assert str(folder) in err


def test_a_misspelt_key_names_the_key(capsys):
    err = one_line_error(capsys, ["run", "--set", "estimator.force_treshold=2"])
    assert err.startswith("hapticlab run: error: estimator.force_treshold: unknown option")


def test_an_unknown_table_names_it(capsys):
    err = one_line_error(capsys, ["run", "--set", "sesion.duration=2"])
    assert err.startswith("hapticlab run: error: sesion.duration: unknown table 'sesion'")


def test_a_bug_keeps_its_traceback(monkeypatch, tmp_path):
    """A plain ValueError from numpy inside hapticlab is not the user's mistake: it propagates."""

    def broken(args):
        raise ValueError("operands could not be broadcast together with shapes (3,) (4,)")

    parser = cli.build_parser(load_plugins=False)
    monkeypatch.setattr(cli, "build_parser", lambda load_plugins=True: parser)
    sub = next(a for a in parser._actions if a.dest == "command")
    sub.choices["recover"].set_defaults(func=broken)
    with pytest.raises(ValueError, match="could not be broadcast"):
        main(["recover", str(tmp_path / "a.mcap"), "-o", str(tmp_path / "b.mcap")])


def test_a_master_port_that_does_not_exist_is_the_users_to_fix(capsys, tmp_path):
    """A device that cannot be opened for a reason in the config: one line naming the key, exit 2, file kept."""
    out = tmp_path / "no_master.mcap"
    code = main(
        [
            "run",
            "--duration",
            "1",
            "--out",
            str(out),
            "--set",
            "session.realtime=false",
            "--set",
            "haptic.name=serial",
            "--set",
            f"haptic.port={tmp_path / 'ttyACM7'}",
        ]
    )
    err = capsys.readouterr().err
    assert code == 2 and "haptic.port" in err and "ttyACM7" in err
    assert out.exists()  # the session's recording holds the failure (and nothing is lost)


def test_the_run_summary_shows_every_parameter_unidentified_ones_too(capsys, tmp_path):
    """``hapticlab run``'s summary: parameters the motion has not identified are NaN (kalman's cog_S a second
    into the demo, with its torque stage started once the force stage has settled), and are printed as such
    (rich took "[nan, nan, nan]" for a style tag and printed nothing); the samples the estimator held out have
    their row."""
    out = tmp_path / "short.mcap"
    settled = "estimator.torque_start=settled"
    assert main(["run", "--duration", "1", "--out", str(out), "--set", "session.realtime=false", "--set", settled]) == 0
    rows = {
        line.split("│")[1].strip(): line.split("│")[2].strip()
        for line in capsys.readouterr().err.splitlines()
        if line.count("│") == 3
    }
    assert rows["cog_S"] == "[nan, nan, nan]"
    assert rows["samples held out (lone outliers)"].isdigit()


def test_a_session_file_that_is_not_utf8_names_the_byte(tmp_path, capsys):
    path = tmp_path / "latin1.toml"
    path.write_bytes('[session]\nname = "café"\n'.encode("latin-1"))
    err = one_line_error(capsys, ["run", str(path)])
    assert err == f"hapticlab run: error: {path}: not UTF-8 text (TOML is): byte 21 (line 2, column 12) is 0xe9"


def test_a_session_file_nested_too_deeply_is_one_line(tmp_path, capsys):
    path = tmp_path / "deep.toml"
    path.write_text("[session]\nx = " + "[" * 5000 + "]" * 5000 + "\n")
    err = one_line_error(capsys, ["run", str(path)])
    assert err == f"hapticlab run: error: {path}: invalid TOML: arrays or tables nested too deeply"


def test_a_session_file_larger_than_a_mebibyte_is_not_read_whole(tmp_path, capsys):
    path = tmp_path / "huge.toml"
    path.write_text("# " + "x" * (1 << 20) + "\n[session]\n")
    err = one_line_error(capsys, ["run", str(path)])
    assert err == f"hapticlab run: error: {path}: larger than 1024 KiB: not a session file"


def test_an_earlier_session_s_calibration_file_is_never_overwritten(tmp_path, capsys):
    """The demo's kalman saves its state beside the recording: an existing one refuses the --out up front."""
    earlier = tmp_path / "x.calibration.json"
    earlier.write_text('{"an earlier session": true}')
    argv = ["run", "--duration", "0.2", "--set", "session.realtime=false", "--out", str(tmp_path / "x.mcap")]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err == (
        f"hapticlab run: error: {earlier} already exists (the estimator's state of an earlier session); "
        "choose another --out (it is never overwritten)"
    )
    assert earlier.read_text() == '{"an earlier session": true}' and not (tmp_path / "x.mcap").exists()
    assert main([*argv[:-1], str(tmp_path / "y.mcap")]) == 0  # a free name runs and saves its state
    assert (tmp_path / "y.calibration.json").is_file()


@pytest.mark.parametrize(
    "argv",
    [
        ["compensate", "{zero}", "-o", "{tmp}/out.csv"],
        ["compensate", "{fifo}", "-o", "{tmp}/out.csv"],
        ["discrepancy", "{zero}"],
        ["discrepancy", "{fifo}"],
        ["replay", "{zero}", "--estimator", "rls", "-o", "{tmp}/out.csv"],
        ["replay", "{fifo}.mcap", "--estimator", "rls", "-o", "{tmp}/out.csv"],
        ["recover", "{zero}", "-o", "{tmp}/out.csv"],
        ["recover", "{fifo}.mcap", "-o", "{tmp}/out.csv"],
    ],
)
def test_an_input_that_is_not_a_regular_file_is_refused_before_it_is_read(tmp_path, capsys, argv):
    """A device reads forever (until a MemoryError), a FIFO blocks: each is one line, exit 2, at once."""
    os.mkfifo(tmp_path / "fifo")
    os.mkfifo(tmp_path / "fifo.mcap")
    argv = [a.format(zero="/dev/zero", fifo=tmp_path / "fifo", tmp=tmp_path) for a in argv]
    err = one_line_error(capsys, argv)
    assert err.startswith(f"hapticlab {argv[0]}: error: {argv[1]}: not a regular file"), err
    assert not (tmp_path / "out.csv").exists()


def test_a_warm_start_that_is_not_a_regular_file_is_refused(tmp_path, capsys):
    argv = ["run", "--duration", "0.1", "--set", "session.realtime=false", "--out", str(tmp_path / "x.mcap")]
    err = one_line_error(capsys, [*argv, "--set", "estimator.warm_start=/dev/zero"])
    assert (
        err
        == "hapticlab run: error: estimator: warm_start: /dev/zero is not a regular file (a folder, a device or a FIFO)"
    )


def test_an_output_that_is_not_a_regular_file_is_never_replaced_even_with_force(tmp_path, capsys):
    """``compensate -o <a FIFO or a device node> --force`` would have replaced the node with a file."""
    good = tmp_path / "good.csv"
    good.write_text("t,fx,fy,fz,tx,ty,tz,qw,qx,qy,qz\n0,0,0,-1,0,0,0,1,0,0,0\n0.01,0,0,-1,0,0,0,1,0,0,0\n")
    node = tmp_path / "node"
    os.mkfifo(node)
    err = one_line_error(capsys, ["compensate", str(good), "-o", str(node), "--force"])
    expected = f"-o {node}: is not a regular file (a device, a FIFO or a socket); give a file name"
    assert err == f"hapticlab compensate: error: {expected}"
    assert stat.S_ISFIFO(node.stat().st_mode)
