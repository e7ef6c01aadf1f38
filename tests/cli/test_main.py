"""`metafovea` itself: the parser, exit statuses, and the one place that maps library parameters to flags."""

import subprocess
import sys

import pytest

from metafovea.cli import COMMAND_MODULES, PARAMETER_FLAGS, as_flag_error, build_parser, main
from metafovea.errors import InputError


def test_every_command_is_registered():
    sub = next(a for a in build_parser()._actions if a.dest == "command")  # argparse keeps subparsers here
    names = set(sub.choices)
    assert {"validate", "design", "library", "export", "verify", "psf", "simulate", "import", "reconstruct"} <= names
    assert len(COMMAND_MODULES) == 9  # validate design library layout psf simulate import_ reconstruct study


def test_no_command_prints_help_and_exits_2(capsys):
    assert main([]) == 2
    assert "COMMAND" in capsys.readouterr().out


def test_unknown_option_is_one_line_exit_2(capsys):
    with pytest.raises(SystemExit) as e:
        main(["design", "--no-such-flag"])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--no-such-flag" in err


def test_library_parameters_are_reported_as_the_flag_typed():
    e = as_flag_error("psf", InputError("band_um", [8, 300], "a band below the evanescent limit"))
    assert e.parameter == "--band-um" and "--band-um = [8, 300]" in str(e)
    # a key of a file keeps its name (the user wrote the file, not a flag)
    e = as_flag_error("psf", InputError("band_um", 3, "x", source="s.toml"))
    assert e.parameter == "band_um"
    # a parameter without a flag keeps its name
    assert as_flag_error("psf", InputError("other", 1, "x")).parameter == "other"
    for command, table in PARAMETER_FLAGS.items():
        assert all(flag.startswith("--") for flag in table.values()), command


def test_module_entry_point():
    r = subprocess.run([sys.executable, "-m", "metafovea", "--version"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and r.stdout.startswith("metafovea ")
