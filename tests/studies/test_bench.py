"""``metafovea bench --quick``: the page and the JSON of every stage, and its refusals (no timing assertions)."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time

import pytest

from metafovea.cli import main
from metafovea.errors import InputError
from metafovea.studies.bench import STAGES, check_stages, disk_write_seconds, run_bench


def _numbers(obj):
    if isinstance(obj, dict):
        for v in obj.values():
            yield from _numbers(v)
    elif isinstance(obj, list):
        for v in obj:
            yield from _numbers(v)
    elif isinstance(obj, (int, float)) and not isinstance(obj, bool):
        yield obj


@pytest.fixture(scope="module")
def quick_run(made_once):
    """``metafovea bench --quick`` (its status, its folder): made once per test run (7-20 s) even where two test
    workers share this module's tests."""
    def make(d):
        (d / "rc.txt").write_text(str(main(["-q", "bench", "--quick", "--out", str(d / "b")])))

    d = made_once("bench-quick", make)
    return int((d / "rc.txt").read_text()), d / "b"


@pytest.mark.slow  # the quick bench (every stage at its --quick size): its module runs among the first
def test_quick_bench_writes_the_page_and_the_json_of_every_stage(quick_run):
    rc, out = quick_run
    assert rc == 0
    assert sorted(p.name for p in out.iterdir()) == ["bench.json", "index.html"]  # the scratch folder is gone
    d = json.loads((out / "bench.json").read_text())
    assert list(d["stages"]) == list(STAGES) and d["quick"] is True
    assert d["machine"]["nproc"] >= 1 and d["machine"]["cpu_model"] and d["date"]
    assert d["command"].startswith("metafovea bench --quick")
    page = (out / "index.html").read_text()
    for name, st in d["stages"].items():
        assert st["command"] == f"metafovea bench --stages {name} --quick --out DIR"
        assert st["command"] in page
        assert len(st["load_before"]) == 3 and len(st["load_after"]) == 3
        assert len(st["rows"]) >= 3, name
        for r in st["rows"]:
            assert r["seconds"] > 0, (name, r)
            for k, v in r.items():
                if k.startswith("error") and v is not None:
                    assert v >= 0, (name, r)
        assert all(math.isfinite(v) for v in _numbers(st)), name
        # the JSON writes a NaN as null: none in a row, but the full model's tolerance (it has none)
        assert all(v is not None for r in st["rows"] for k, v in r.items() if k != "tolerance_k"), name
    assert page.count("data:image/png;base64,") == len(STAGES)
    # each stage's measure: errors against a reference, PSNR against the truth, the export beside the disk
    assert all("error" in r for n in ("rcwa", "psf", "simulate") for r in d["stages"][n]["rows"])
    assert all("psnr_db" in r for r in d["stages"]["reconstruct"]["rows"])
    assert all(r["bytes"] > 0 and r["disk_seconds"] > 0 for r in d["stages"]["export"]["rows"])
    # the reduced models stay within their budgets
    assert all(r["within_budget"] for r in d["stages"]["simulate"]["rows"] if r["tolerance_k"] is not None)
    # a field-dependent PSF: the file's patches beat the on-axis kernel in the perifoveal channel at 10 um
    fld = {r["setting"]: r["psnr_db"] for r in d["stages"]["reconstruct"]["rows"]
           if r["series"] == "field-dependent PSF, perifoveal channel"}
    assert fld["wiener, field_psf auto"] > fld["wiener, field_psf on-axis"] + 2.0, fld


def test_nothing_is_overwritten_without_force(quick_run, capsys):
    _, out = quick_run
    before = (out / "bench.json").read_bytes()
    assert main(["bench", "--quick", "--stages", "rcwa", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("metafovea bench: error: --out") and "force" in err[0]
    assert (out / "bench.json").read_bytes() == before


def test_force_replaces_the_files_with_the_stages_asked(tmp_path):
    (tmp_path / "old.txt").write_text("x")
    res = run_bench(tmp_path, quick=True, stages=["export"], force=True)
    assert list(res["stages"]) == ["export"]
    assert json.loads((tmp_path / "bench.json").read_text())["stages"].keys() == {"export"}
    assert (tmp_path / "old.txt").exists()  # only its own two files are written


def _exit_status(argv):
    """``main(argv)``'s exit status, whether argparse exits (SystemExit) or the command returns it."""
    try:
        return main(argv)
    except SystemExit as e:
        return e.code


@pytest.mark.parametrize("argv", [["--stages", "nosuch"], ["--stages", "rcwa", "rcwa"], ["--nosuch-flag"],
                                  ["--quick", "--stages"]])
def test_bad_flags_give_one_line_and_exit_2(argv, tmp_path, capsys):
    assert _exit_status(["bench", "--out", str(tmp_path / "o"), *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(("metafovea bench: error:", "metafovea: error:")), err
    assert not (tmp_path / "o").exists()  # refused before anything is created


def test_check_stages():
    assert check_stages(None) == STAGES
    assert check_stages(["export", "rcwa"]) == ("rcwa", "export")  # run in the page's order
    with pytest.raises(InputError, match="stages"):
        check_stages(["rcwa", "nope"])


def test_disk_write_seconds_writes_and_removes_its_file(tmp_path):
    dt, mode = disk_write_seconds(tmp_path / "d.bin", 1 << 20)
    assert dt > 0 and mode in ("O_DIRECT", "buffered")
    assert not list(tmp_path.iterdir())


@pytest.mark.skipif(sys.platform != "linux", reason="process groups (Linux)")
def test_ctrl_c_stops_the_bench_with_one_line_and_writes_nothing(tmp_path):
    """SIGINT to the process group while the quick bench's first stage runs: exit 130, 'interrupted' the last line,
    no traceback, nothing left in the output folder (no page, no JSON, no scratch file)."""
    out = tmp_path / "b"
    cmd = [sys.executable, "-c", "from metafovea.cli import console_main; raise SystemExit(console_main())",
           "bench", "--quick", "--out", str(out)]
    p = subprocess.Popen(cmd, start_new_session=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    first = p.stderr.readline()  # the first progress line: the RCWA reference is being solved
    assert "rcwa" in first, first
    time.sleep(0.5)
    t0 = time.monotonic()
    os.killpg(p.pid, signal.SIGINT)
    _, err = p.communicate(timeout=60)
    assert p.returncode == 130, err[-800:]
    assert "Traceback" not in err and err.strip().splitlines()[-1] == "interrupted", err[-800:]
    assert time.monotonic() - t0 < 30
    assert not out.exists() or not list(out.iterdir()), list(out.rglob("*"))


def test_the_page_renders_cleanly(quick_run, browser_check):
    """The page in a browser: no overflow at 800 and 1400 px, every figure loads and has its text, no raw Python
    values (the rows' dicts and lists written as a person reads them)."""
    _, out = quick_run
    browser_check(out / "index.html")
