"""`metafovea` itself: the parser, exit statuses, and the one place that maps library parameters to flags."""

import subprocess
import sys

import pytest

from metafovea.cli import COMMAND_MODULES, COMMANDS, build_parser, main
from metafovea.cli.flags import PARAMETER_FLAGS, as_flag_error
from metafovea.errors import InputError


def test_every_command_is_registered():
    sub = next(a for a in build_parser()._actions if a.dest == "command")  # argparse keeps subparsers here
    names = set(sub.choices)
    assert {"validate", "design", "library", "export", "verify", "psf", "simulate", "import", "reconstruct",
            "codesign", "bench"} <= names
    assert len(COMMAND_MODULES) == 11  # validate design library layout psf simulate import_ reconstruct codesign study
    # bench


def test_a_command_line_builds_only_its_commands_parser():
    import importlib

    full = next(a for a in build_parser()._actions if a.dest == "command")
    # the map names every command's module: each registers exactly the commands the map gives it
    assert set(full.choices) == set(COMMANDS) and set(COMMANDS.values()) == set(COMMAND_MODULES)
    for name in COMMAND_MODULES:
        only = next(a for a in build_parser([next(c for c, m in COMMANDS.items() if m == name)])._actions
                    if a.dest == "command")
        assert set(only.choices) == {c for c, m in COMMANDS.items() if m == name}, name
        assert importlib.import_module(f"metafovea.cli.{name}")
    # options before the command, and the same options either way
    p = build_parser(["-v", "-q", "reconstruct", "x.npz"])
    assert p.parse_args(["-v", "-q", "reconstruct", "x.npz"]).command == "reconstruct"
    full_opts = {a.dest for a in full.choices["reconstruct"]._actions}
    only_opts = {a.dest for a in next(a for a in p._actions if a.dest == "command").choices["reconstruct"]._actions}
    assert full_opts == only_opts
    # an unknown first word builds the whole parser (argparse names the choices)
    assert set(next(a for a in build_parser(["nosuch"])._actions if a.dest == "command").choices) == set(COMMANDS)


def _fresh_python(code: str) -> str:
    """``code``'s output in a new interpreter (what it imports is then its own doing)."""
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()


def test_known_alpha_reconstruct_starts_without_the_other_solvers():
    """A known-alpha run imports neither the unknown-alpha, deep-prior or deconvolution solvers nor the other
    commands' packages (start-up counts in the file-to-file throughput, BENCHMARKS.md)."""
    heavy = ("metafovea.reconstruct.alternating", "metafovea.reconstruct.deep_prior",
             "metafovea.reconstruct.deconvolve", "metafovea.rcwa", "metafovea.recordings", "jax")
    assert _fresh_python("import sys; from metafovea.cli import build_parser; build_parser(['reconstruct', 'x.npz']); "
                         "import metafovea.reconstruct.api, metafovea.cli.reconstruct; "
                         f"print([m for m in {heavy!r} if m in sys.modules])") == "[]"
    # the package's functions named as their modules stay functions once those modules are loaded
    assert _fresh_python("import types; import metafovea.reconstruct.video, metafovea.reconstruct.alternating, "
                         "metafovea.reconstruct.snapshot, metafovea.reconstruct.denoise; import metafovea.reconstruct "
                         "as r; from metafovea.reconstruct import alternating, video, snapshot, denoise; "
                         "print(all(callable(f) and not isinstance(f, types.ModuleType) for f in (alternating, video, "
                         "snapshot, denoise, r.video, r.alternating)), sorted(r.__all__) == sorted(r._HOMES))"
                         ) == "True True"


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


def test_deconvolve_without_a_name_runs_the_default_method():
    from metafovea.cli import build_parser
    from metafovea.reconstruct import DECONVOLUTION_METHODS, DEFAULT_DECONVOLUTION

    def parsed(*argv: str):
        return build_parser(["reconstruct"]).parse_args(["reconstruct", "x.npz", *argv])

    assert parsed("--deconvolve").deconvolve == DEFAULT_DECONVOLUTION == "wavelet"
    assert parsed("--deconvolve", "wiener", "--psf", "p.npz").deconvolve == "wiener"
    assert parsed("--deconvolve", "--psf", "p.npz").deconvolve == "wavelet"
    assert parsed().deconvolve is None
    assert set(DECONVOLUTION_METHODS) == {"wavelet", "wiener", "tv"}
