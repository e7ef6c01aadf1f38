"""The co-design run on a small camera: it improves the band MTF, never past the line bound, its files load as a
design, the production engine agrees with it, the full-size lens is refused with the count it needs, and the
command's bad input and existing output are refused in one line."""

from __future__ import annotations

import json

import pytest

from metafovea.cli import main
from metafovea.codesign import CodesignOptions, OptimizeOptions, codesign, run_codesign, spectral_sampling
from metafovea.config import LensDesign, SystemDesign, load_system, platform_toml, system_toml
from metafovea.design_report import design_toml
from metafovea.errors import InputError

FOV = LensDesign("foveal", 2000.0, 1000.0, polarization="x")  # F/2, ~13 depths of focus over 8-14 um
PER = LensDesign("perifoveal", 1000.0, 1000.0, polarization="y")
SYSTEM = SystemDesign(foveal=FOV, perifoveal=PER, lens_to_sensor_um=(2000.0, 1000.0))
OPTS = CodesignOptions(n_coefficients=1, size_px=9, optimize=OptimizeOptions(steps=10, learning_rate=0.1,
                                                                              progress=False))


@pytest.fixture(scope="module")
def small_system_file(tmp_path_factory):
    d = tmp_path_factory.mktemp("small")
    (d / "platform.toml").write_text(platform_toml(SYSTEM.platform))
    (d / "foveal.toml").write_text(design_toml(FOV))
    (d / "perifoveal.toml").write_text(design_toml(PER))
    (d / "system.toml").write_text(system_toml(SYSTEM))
    return d / "system.toml"


@pytest.fixture(scope="module")
def result(small_system_file, made_once):
    """The run's summary (what :func:`run_codesign` returns: its codesign.json) and folder: made once per test run
    (~20 s) even where two test workers share this module's tests."""
    out = made_once("codesign-run", lambda d: run_codesign(small_system_file, OPTS, d / "cd")) / "cd"
    return json.loads((out / "codesign.json").read_text()), out


@pytest.mark.slow  # the co-design run (~20 s, made once) at a small size: 9 px, one coefficient, 10 steps
def test_the_run_gains_within_the_line_bound_and_production_agrees(result):
    summary, _ = result
    d = summary["lenses"]["foveal"]
    assert d["mtf_area"] > d["mtf_area_hyperbolic"]
    assert 1.0 < d["gain"] <= d["line_bound_gain_limit"] * 1.02
    pc = d["production_check"]
    assert pc["codesigned"]["engine"] == "rs"  # an added phase goes to the exact engine
    assert pc["gain_production"] == pytest.approx(d["gain"], abs=0.03)
    assert pc["hyperbolic"]["max_difference_of_peak"] < 1e-3
    assert any("short" in line for line in d["bandwidth_limit"])


def test_a_gain_above_the_line_bound_is_said_to_be_an_artefact(result):
    """A 9-px window on a 0.1 um band reported 1.155x against a bound of 1.004x that no phase can exceed, without a
    word: such a gain is now a warning naming the window; the default window's 1.006x against 1.004x is not."""
    from metafovea.codesign.run import bound_warnings

    (w,) = bound_warnings(1.155, 1.004, 9, 34.0)
    assert "exceeds the line bound's 1.004x" in w and "9 px of 34 um" in w and "size_px" in w
    assert bound_warnings(1.006, 1.004, 31, 34.0) == []
    d = result[0]["lenses"]["foveal"]
    assert bool(d["warnings"]) == (d["gain"] > d["line_bound_gain_limit"] * 1.01)  # the run's own summary


def test_the_written_files_are_a_design(result):
    summary, out = result
    s = load_system(out / "system.toml")
    assert s.foveal.phase_poly_rad == pytest.approx(summary["lenses"]["foveal"]["phase_poly_rad"])
    assert s.perifoveal == PER and s.lens_to_sensor_um == SYSTEM.lens_to_sensor_um
    assert "line bound" in (out / "report.html").read_text()
    assert json.loads((out / "codesign.json").read_text())["objective"] == "mtf"


def test_the_paper_lens_is_refused_with_what_it_needs():
    n, why = spectral_sampling(SystemDesign.paper().foveal, 150_000.0, (8.0, 14.0))
    assert n > 1000 and "quarter wave" in why
    with pytest.raises(InputError, match="line bound"):
        codesign(SystemDesign.paper(), CodesignOptions(max_wavelengths=400, optimize=OptimizeOptions(steps=1)))


def test_the_command_says_when_the_cap_it_refuses_is_its_default(tmp_path, capsys):
    # `metafovea codesign` on the paper's camera: the default cap (400 samples) is below what the foveal lens needs;
    # the line says so and names the value that lifts it, not only the flag the user never typed
    n, _ = spectral_sampling(SystemDesign.paper().foveal, 150_000.0, (8.0, 14.0))
    rc = main(["codesign", "--out", str(tmp_path / "d")])
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and "line bound" in line and f"400 is the default cap; --max-wavelengths {n} lifts it" in line
    rc = main(["codesign", "--out", str(tmp_path / "g"), "--max-wavelengths", "400"])
    (given,) = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and f">= {n}" in given and "default cap" not in given


@pytest.mark.parametrize("flags, word", [(["--coefficients", "0"], "--coefficients"),
                                         (["--lenses", "middle"], "--lenses"),
                                         (["--band", "14", "8"], "--band"),
                                         (["--objective", "psnr"], "--objective"),
                                         (["--size-px", "20"], "--size-px")])
def test_bad_flags_give_one_line_and_exit_2(flags, word, small_system_file, tmp_path, capsys):
    rc = main(["codesign", str(small_system_file), "--out", str(tmp_path / "o"), *flags])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and word in err[0]


def test_a_finished_run_is_not_overwritten_without_force(result, small_system_file, capsys):
    _, out = result
    rc = main(["codesign", str(small_system_file), "--out", str(out), "--steps", "1"])
    err = capsys.readouterr().err
    assert rc == 2 and "--force" in err


def test_the_band_weights_follow_the_system_filter():
    """With the system's 10 um filter on, the weights sit on the filter (radiometry's (centre, FWHM) convention) and
    the line bound leaves nothing to win; without it they follow the 300 K Planck curve over the band."""
    from dataclasses import replace

    import numpy as np

    from metafovea.codesign import band_mtf_bound
    from metafovea.codesign.run import band_weights
    from metafovea.radiometry import system_filter_um

    wl = np.linspace(8.0, 14.0, 601)
    on = replace(SystemDesign.paper(), filter_enabled=True)
    w_on, w_off = band_weights(wl, on, (8.0, 14.0)), band_weights(wl, SystemDesign.paper(), (8.0, 14.0))
    assert abs(float(w_on @ wl) - on.filter_center_um) < 0.05 and float(w_on[np.abs(wl - 10.0) > 1.0].sum()) < 0.01
    assert float(w_off @ wl) > 10.5 and w_off.sum() == pytest.approx(1.0)
    b = band_mtf_bound(on.foveal, (8.0, 14.0), [5.0, 10.0], filter_um=system_filter_um(on))
    assert b.gain_limit < 1.01


def test_the_run_never_writes_over_its_input_and_a_refusal_leaves_no_folder(small_system_file, tmp_path, capsys):
    """`codesign cd/system.toml --out cd --force` rewrote the system and lens files it had read; a run refused
    before its first step (the default cap on the paper's lens) left an empty --out folder."""
    import shutil

    d = tmp_path / "cd"
    shutil.copytree(small_system_file.parent, d)
    before = {p.name: p.read_bytes() for p in d.iterdir()}
    assert main(["codesign", str(d / "system.toml"), "--out", str(d), "--force", "--steps", "2", "--size-px", "9",
                 "--no-check"]) == 2
    assert "a folder other than the input's" in capsys.readouterr().err
    assert {p.name: p.read_bytes() for p in d.iterdir()} == before
    assert main(["codesign", "--out", str(tmp_path / "cd0")]) == 2
    assert "max_wavelengths" in capsys.readouterr().err and not (tmp_path / "cd0").exists()


def test_a_run_stopped_in_its_final_writes_resumes(result, small_system_file, tmp_path):
    """A Ctrl-C between the design files and the page left checkpoints and system files; the rerun was refused
    (only a folder of checkpoints resumed). It resumes now; a folder with the page (a finished run) still does not."""
    import shutil

    _, out = result
    part = tmp_path / "part"
    part.mkdir()
    for name in ("checkpoint_foveal.npz", "system.toml", "foveal.toml", "platform.toml"):
        shutil.copy(out / name, part / name)
    summary = run_codesign(small_system_file, OPTS, part, check=False)
    assert (part / "report.html").is_file() and summary["lenses"]["foveal"]["gain"] > 1.0
    with pytest.raises(InputError, match="an empty folder"):
        run_codesign(small_system_file, OPTS, part, check=False)


def test_an_input_lens_with_an_added_phase_is_said_to_be_replaced():
    """Co-designing a co-designed system started from the hyperbola again and dropped the input's phase_poly_rad
    without a word."""
    from dataclasses import replace

    from metafovea.codesign.run import codesign_lens

    system = SystemDesign.paper()
    system = replace(system, foveal=replace(system.foveal, phase_poly_rad=(0.5, -0.2)))
    with pytest.warns(UserWarning, match="already carries an added phase"), pytest.raises(InputError):
        codesign_lens(system, "foveal", CodesignOptions(max_wavelengths=3))  # refused right after: no run
