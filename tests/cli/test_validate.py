"""``metafovea validate`` through :func:`metafovea.cli.main`: bad flags fail with one line and exit status 2
before any work (the run itself is tested in tests/test_validate.py)."""

import pytest

from metafovea.cli import main


def test_validate_cli_bad_input(tmp_path, capsys):
    assert main(["validate", "--frames", "1", "--out", str(tmp_path / "x")]) == 2
    assert "--frames" in capsys.readouterr().err
    d = tmp_path / "full"
    d.mkdir()
    (d / "f").write_text("x")
    assert main(["validate", "--out", str(d)]) == 2
    assert "--force" in capsys.readouterr().err


@pytest.mark.parametrize("argv, name", [(["--frames", "2"], "--frames"), (["--dip-steps", "0"], "--dip-steps"),
                                        (["--scene", "no-such-scene"], "scene"), (["--seed", "-1"], "--seed")])
def test_validate_bad_arguments_fail_before_any_work(tmp_path, capsys, argv, name):
    out = tmp_path / "v"
    assert main(["validate", *argv, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert name in err and err.count("\n") == 1
    assert not out.exists()


def test_validate_refuses_a_celsius_scene_before_any_work_and_names_the_flag(tmp_path, capsys):
    """validate's --scene takes the same files as simulate's: a file in degrees Celsius is one line naming
    --scene-unit, before the library and PSF work."""
    import numpy as np

    np.save(tmp_path / "room.npy", np.full((20, 20), 22.0))
    out = tmp_path / "v"
    assert main(["validate", "--scene", str(tmp_path / "room.npy"), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert f"--scene {tmp_path / 'room.npy'}: " in err and "--scene-unit celsius converts them" in err
    assert err.count("\n") == 1
    assert not out.exists()
