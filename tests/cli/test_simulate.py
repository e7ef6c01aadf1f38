"""``metafovea simulate``: flags, files, exit statuses and messages (through ``metafovea.cli.main``)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from metafovea.cli import main
from metafovea.imaging.kernels import MAX_PSF_SIZE
from metafovea.measurement import Measurement


def test_cli_simulate(tmp_path, designs_dir, capsys):
    import tifffile

    out = tmp_path / "meas.npz"
    args = ["simulate", str(designs_dir / "system.toml"), "--scene", "bars", "--frames", "3", "--psf",
            "gaussian:12", "--supersample", "1", "--out", str(out), "--json"]
    assert main(args) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["frames"] == 3 and summary["shape"] == [290, 290]
    assert out.is_file() and (tmp_path / "meas.tif").is_file() and (tmp_path / "meas_preview.png").is_file()
    assert tifffile.imread(tmp_path / "meas.tif").shape == (3, 290, 290)
    assert main(args) == 2  # refuses to overwrite
    assert main(args[:-3] + ["--out", str(tmp_path / "x.npz"), "--frames", "0"]) == 2
    assert main(["simulate", "--scene", "nope.npy", "--out", str(tmp_path / "y.npz")]) == 2
    assert main(["simulate", str(tmp_path / "missing.toml"), "--out", str(tmp_path / "z.npz")]) == 2
    err = capsys.readouterr().err
    assert "frames" in err and "scene" in err


def test_cli_simulate_text_summary_and_optional_outputs(tmp_path, capsys):
    out = tmp_path / "m.npz"
    assert main(["simulate", "--scene", "uniform", "--frames", "2", "--psf", "airy", "--out", str(out),
                 "--no-tiff", "--no-preview"]) == 0
    text = capsys.readouterr().out
    assert text.startswith("scene uniform: 2 frames 290x290 (DN)") and "haze fraction foveal" in text
    # the default's shift-invariant PSF says that it is a simplification, and what models the field dependence
    assert "field dependence of the PSFs: field_patches = 1: the on-axis kernel over the whole field, a " \
           "simplification" in text and "'auto' models it" in text
    assert f"measurement: {out}" in text and "tiff" not in text
    assert out.is_file() and not (tmp_path / "m.tif").exists() and not (tmp_path / "m_preview.png").exists()
    assert main(["simulate", "--scene", "uniform", "--out", str(tmp_path / "m.txt")]) == 2
    assert "--out = " in capsys.readouterr().err


def test_cli_list_scenes(capsys):
    assert main(["simulate", "--list-scenes", "--json"]) == 0
    scenes = json.loads(capsys.readouterr().out)
    assert "siemens-star" in scenes and "hand" in scenes
    assert main(["simulate", "--list-scenes"]) == 0
    assert capsys.readouterr().out.startswith("siemens-star ")


def test_large_psf_window_is_refused_by_the_flag(tmp_path, capsys):
    """--psf-size up to 4097 was accepted and asked the Airy model for a (4097*7)^2 grid (tens of GB)."""
    assert main(["simulate", "--psf", "airy", "--psf-size", str(MAX_PSF_SIZE + 2), "--frames", "1",
                 "--out", str(tmp_path / "m.npz")]) == 2
    err = capsys.readouterr().err
    assert "--psf-size" in err and not (tmp_path / "m.npz").exists()


def test_simulate_never_overwrites_its_scene_file_even_with_force(tmp_path, monkeypatch, capsys):
    """--scene s.npz --out s.npz destroyed the scene, even with --force; k.tif as scene and k.npz as out
    overwrote it with the TIFF stack."""
    import tifffile

    monkeypatch.chdir(tmp_path)
    np.savez("s.npz", temperature_k=np.full((20, 20), 300.0))
    before = (tmp_path / "s.npz").read_bytes()
    assert main(["simulate", "--scene", "s.npz", "--out", "s.npz", "--force", "--frames", "1", "--psf", "airy"]) == 2
    assert "--out" in capsys.readouterr().err and (tmp_path / "s.npz").read_bytes() == before
    np.save("k.npy", np.full((20, 20), 300.0))
    tifffile.imwrite("k.tif", np.full((20, 20), 300.0, np.float32))  # the TIFF written next to k.npz
    assert main(["simulate", "--scene", "k.tif", "--out", "k.npz", "--force", "--frames", "1", "--psf", "airy"]) == 2
    assert "k.tif" in capsys.readouterr().err


def test_cli_calibration_frames_feed_reconstruct_fpn_calibration(tmp_path, capsys):
    """--calibration-frames N records closed-shutter frames, so `reconstruct --fpn calibration` works on a CLI-made
    file; the estimate is scored against the file's true pattern."""
    import json

    import numpy as np

    out = tmp_path / "c.npz"
    assert main(["simulate", "--scene", "bars", "--frames", "8", "--psf", "airy", "--calibration-frames", "16",
                 "--out", str(out), "--no-tiff", "--no-preview"]) == 0
    with np.load(out) as z:
        assert z["calibration"].shape[0] == 16
    capsys.readouterr()
    assert main(["reconstruct", str(out), "--fpn", "calibration", "--no-figures", "--json",
                 "--out", str(tmp_path / "r.npz")]) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["fpn"] == "calibration" and s["metrics"]["fpn_rms_error"] < 0.5 * s["metrics"]["fpn_rms_true"]
    assert main(["simulate", "--calibration-frames", "-1", "--out", str(tmp_path / "d.npz")]) == 2
    assert "--calibration-frames" in capsys.readouterr().err


def test_default_simulate_then_default_reconstruct_round_trips(tmp_path, capsys):
    """The default simulate added fixed-pattern noise but wrote no shutter frames, and the default reconstruct left the
    pattern in: a foveal image at -8.1 dB, with no hint (and --fpn calibration refused). Now simulate writes 16
    shutter frames by default and reconstruct's --fpn auto uses them and says so: the foveal image is within 0.5 dB
    of the same simulation without fixed-pattern noise. (Small and fast: the bars scene, 8 frames, Airy PSFs.)"""
    fast = ["--scene", "bars", "--frames", "8", "--psf", "airy", "--no-tiff", "--no-preview"]
    for name, extra in (("m", []), ("clean", ["--no-fpn"])):
        assert main(["simulate", *fast, *extra, "--out", str(tmp_path / f"{name}.npz")]) == 0
    with np.load(tmp_path / "m.npz") as z:
        assert z["calibration"].shape[0] == 16
    capsys.readouterr()
    assert main(["reconstruct", str(tmp_path / "m.npz"), "--no-figures"]) == 0
    text = capsys.readouterr().out
    assert "fixed-pattern noise: calibration, from the file's 16 shutter frames (--fpn auto)" in text
    scores = {}
    for name in ("m", "clean"):
        assert main(["reconstruct", str(tmp_path / f"{name}.npz"), "--no-figures", "--json", "--force"]) == 0
        scores[name] = json.loads(capsys.readouterr().out)
    assert scores["m"]["fpn_mode"] == "calibration" and "shutter frames" in scores["m"]["fpn_auto"]
    assert scores["m"]["metrics"]["psnr_x1"] > scores["clean"]["metrics"]["psnr_x1"] - 0.5
    # without shutter frames the file's declared pattern is estimated blind, and said
    assert main(["simulate", *fast, "--calibration-frames", "0", "--out", str(tmp_path / "n.npz")]) == 0
    capsys.readouterr()
    assert main(["reconstruct", str(tmp_path / "n.npz"), "--no-figures", "--json"]) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["fpn_mode"] == "prior" and "blind" in s["fpn_auto"]


def test_simulate_off_a_terminal_says_what_it_computes(tmp_path, capsys, monkeypatch):
    """A first `metafovea simulate` computes the RCWA library, the posts at oblique incidence and the channels' PSFs
    (minutes, cached afterwards) and printed nothing meanwhile off a terminal: each long step now writes a line every
    PROGRESS_LINE_S (shortened here) saying what it computes; -q silences it."""
    import metafovea.parallel
    from metafovea.imaging.simulate import clear_caches

    monkeypatch.setattr(metafovea.parallel, "PROGRESS_LINE_S", 0.01, raising=False)
    clear_caches()  # the camera of an earlier simulation in this process would be reused at once
    argv = ["simulate", "--scene", "bars", "--frames", "2", "--psf", "airy", "--no-tiff", "--no-preview"]
    assert main([*argv, "--out", str(tmp_path / "a.npz")]) == 0
    err = capsys.readouterr().err
    assert "metafovea: simulate: the lenses' posts and optical train" in err
    assert "metafovea: simulate: the channels' PSFs (airy;" in err
    assert main([*argv, "--out", str(tmp_path / "b.npz"), "-q"]) == 0
    assert "metafovea: simulate" not in capsys.readouterr().err



def _room_celsius() -> np.ndarray:
    """A room in degrees Celsius (20-35), as a thermal camera's software exports it."""
    c = np.full((30, 30), 21.0, np.float32)
    c[8:20, 10:22] = 34.5
    return c


def test_a_float_rgb_tiff_scene_is_one_line_naming_the_flag(tmp_path, capsys, cli_error):
    """A float RGB TIFF was simulated as a video of 30 frames, 40 x 3 pixels each, without a word."""
    import imageio.v3 as iio

    rgb = np.random.default_rng(0).random((30, 40, 3)).astype(np.float32)
    iio.imwrite(tmp_path / "photo.tif", rgb)
    out = tmp_path / "m.npz"
    assert main(["simulate", "--scene", str(tmp_path / "photo.tif"), "--out", str(out)]) == 2
    err = cli_error(capsys)
    assert "\n" not in err and err.startswith(f"metafovea simulate: error: --scene {tmp_path / 'photo.tif'}: ")
    assert "one channel (a temperature map in kelvin)" in err and "(30, 40, 3)" in err and "3 samples per pixel" in err
    assert "8- or 16-bit PNG or TIFF" in err and not out.exists()


def test_a_celsius_scene_is_refused_and_scene_unit_celsius_converts_it(tmp_path, capsys, cli_error):
    """A scene in degrees Celsius (20-35) was simulated as 20-35 K without a word: now one line naming --scene and
    the unit, and --scene-unit celsius gives the frames of the same scene in kelvin, saying what it converted."""
    import tifffile

    c = _room_celsius()
    tifffile.imwrite(tmp_path / "room_c.tif", c)
    np.save(tmp_path / "room_c.npy", c)
    np.save(tmp_path / "room_k.npy", c.astype(np.float64) + 273.15)
    for name in ("room_c.tif", "room_c.npy"):
        assert main(["simulate", "--scene", str(tmp_path / name), "--out", str(tmp_path / "m.npz")]) == 2
        err = cli_error(capsys)
        assert "\n" not in err and err.startswith(f"metafovea simulate: error: --scene {tmp_path / name}: ")
        assert "temperatures in kelvin" in err and "look like degrees Celsius: --scene-unit celsius converts" in err
    fast = ["--frames", "3", "--psf", "airy", "--posts", "ideal", "--no-train", "--no-tiff", "--no-preview"]
    assert main(["simulate", "--scene", str(tmp_path / "room_c.npy"), "--scene-unit", "celsius",
                 "--out", str(tmp_path / "c.npz"), *fast]) == 0
    assert "scene values: degrees Celsius converted to kelvin: T_K = T_C + 273.15" in capsys.readouterr().out
    assert main(["simulate", "--scene", str(tmp_path / "room_k.npy"), "--out", str(tmp_path / "k.npz"), "--json",
                 *fast]) == 0
    assert "scene_conversion" not in json.loads(capsys.readouterr().out)
    with np.load(tmp_path / "c.npz") as zc, np.load(tmp_path / "k.npz") as zk:
        np.testing.assert_array_equal(zc["frames"], zk["frames"])
    assert main(["simulate", "--scene", "bars", "--scene-unit", "celsius", "--out", str(tmp_path / "b.npz")]) == 2
    assert "--scene-unit = 'celsius'" in cli_error(capsys)
    with pytest.raises(SystemExit) as e:
        main(["simulate", "--scene", str(tmp_path / "room_c.npy"), "--scene-unit", "fahrenheit"])
    assert e.value.code == 2 and "--scene-unit: invalid choice: 'fahrenheit'" in cli_error(capsys)


def test_a_cold_pixel_warning_names_the_flag(tmp_path, capsys):
    """A library warning's keyword (scene_unit='celsius') is printed as the flag to type."""
    t = np.full((30, 30), 300.0)
    t[0, 0] = 20.0
    np.save(tmp_path / "cold.npy", t)
    assert main(["simulate", "--scene", str(tmp_path / "cold.npy"), "--out", str(tmp_path / "m.npz"), "--frames", "1",
                 "--psf", "airy", "--posts", "ideal", "--no-train", "--no-tiff", "--no-preview"]) == 0
    err = capsys.readouterr().err
    assert err.count("colder than any sky") == 1 and "--scene-unit celsius converts it" in err


def test_cli_tolerance_prints_the_plan_and_writes_it_to_the_json_and_the_file(tmp_path, capsys):
    """--tolerance-k: the plan table printed before the summary, in the --json summary and the Measurement's
    metadata (``model``), saying the model is REDUCED."""
    from metafovea.measurement import Measurement

    out = tmp_path / "m.npz"
    base = ["simulate", "--scene", "uniform", "--frames", "2", "--psf", "airy", "--no-tiff"]
    assert main(base + ["--tolerance-k", "0.5", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert text.startswith("REDUCED MODEL for a tolerance of 0.5 K rms")
    assert "supersampling" in text and "temporal noise" in text and "scene uniform:" in text
    assert (tmp_path / "m_preview.png").is_file()
    model = Measurement.load(out).meta["model"]
    assert model["reduced"] and model["plan"]["tolerance_k_rms"] == 0.5
    # (the summaries only: no preview figure, ~1/2 of each run's time)
    assert main(base + ["--tolerance-k", "0.5", "--out", str(tmp_path / "j.npz"), "--json", "--no-preview"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["model"]["reduced"] and summary["plan"]["reduce"] == model["reduce"]
    assert main(base + ["--out", str(tmp_path / "f.npz"), "--json", "--no-preview"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["model"]["reduced"] is False and "plan" not in summary


@pytest.mark.parametrize("bad", ["0", "-1", "200", "abc"])
def test_cli_a_bad_tolerance_is_one_line_naming_the_flag(bad, tmp_path, capsys, cli_error):
    assert main(["simulate", "--scene", "uniform", "--frames", "1", "--psf", "airy", f"--tolerance-k={bad}",
                 "--out", str(tmp_path / "m.npz")]) == 2
    err = cli_error(capsys)
    assert len(err.splitlines()) == 1 and err.count("--tolerance-k") >= 1
    if bad != "abc":
        assert "0 K < --tolerance-k <= 100 K" in err
    assert not (tmp_path / "m.npz").exists()


def test_cli_simulate_says_which_psf_request_it_used(tmp_path, capsys):
    """With the optics PSFs the summary names each channel's error request, why, and whether the kernel met it."""
    out = tmp_path / "m.npz"
    assert main(["simulate", "--frames", "1", "--psf", "optics", "--out", str(out), "--no-tiff", "--no-preview"]) == 0
    text = capsys.readouterr().out
    for c in ("foveal", "perifoveal"):
        line = next(ln for ln in text.splitlines() if ln.startswith(f"{c} PSF kernels: the recording asks for"))
        assert "one frame's noise" in line and "scene range" in line and "within the" in line


def test_inputs_a_hunt_found_wrong(tmp_path, capsys):
    """A pixel far below the wavelength (1 nm: the kernels asked for 454 GiB and crashed) is one line with the
    range; a phase of 1e20 degrees still turns the polariser (its angle plus 1e20 was a constant in float64); a
    noiseless camera (--netd 0, in the flag's range) writes a file the recording schema accepts."""
    fast = ["--scene", "uniform", "--psf", "airy", "--no-tiff", "--no-preview"]
    assert main(["simulate", *fast, "--frames", "2", "--pixel-um", "0.001", "--out", str(tmp_path / "p.npz")]) == 2
    err = capsys.readouterr().err
    assert "--pixel-um = 0.001 is invalid" in err and "1 um <= --pixel-um <= 1000 um" in err and "Traceback" not in err
    assert main(["simulate", *fast, "--frames", "12", "--polarizer", "sync", "--phase-deg", "1e20",
                 "--out", str(tmp_path / "ph.npz")]) == 0
    a = Measurement.load(tmp_path / "ph.npz").alpha
    assert a.max() - a.min() > 0.5
    assert main(["simulate", *fast, "--frames", "2", "--netd", "0", "--out", str(tmp_path / "n.npz")]) == 0
    assert Measurement.load(tmp_path / "n.npz").meta["netd_k"] == 0


def test_a_video_scene_shorter_than_the_recording_is_said_to_repeat(tmp_path, capsys):
    np.save(tmp_path / "vid.npy", 290.0 + 10.0 * np.random.default_rng(0).random((5, 32, 32)))
    fast = ["--scene", str(tmp_path / "vid.npy"), "--psf", "airy", "--no-tiff", "--no-preview"]
    assert main(["simulate", *fast, "--frames", "24", "--out", str(tmp_path / "a.npz")]) == 0
    err = capsys.readouterr().err
    assert "the scene's 5 frames at 12 frames/s last 0.417 s" in err and "it plays 4.8 times" in err, err
    assert main(["simulate", *fast, "--frames", "5", "--out", str(tmp_path / "b.npz")]) == 0
    assert "plays" not in capsys.readouterr().err
