"""FLIR's radiometric files (JPEG, FFF, SEQ) through ``metafovea import``: counts, the file's Planck constants and
object parameters, kelvin.

The files are written here byte by byte from ExifTool's documentation of the format (``Image::ExifTool::FLIR``: the
APP1 "FLIR" segments of a JPEG, the FFF header and its record directory, the ``RawData`` record and the
``CameraInfo`` record with ``PlanckR1/B/F/O/R2``, ``Emissivity``, ``ReflectedApparentTemperature``, ...), not by
the importer, which reads them through flyr and flirpy. Where perl is there, ExifTool itself (the copy flirpy ships)
reads the same files back, which checks the writer against the format's reference reader.

The truth is FLIR's object temperature computed in this file from the raw counts and the constants written (the
raw-to-temperature formula of Minkina & Dudzik, as ExifTool's forum and Thermimage give it), checked against the
readers' own conversions (flyr's ``kelvin``, flirpy's ``raw2temp``). The importer keeps the counts and folds the
conversion into the Measurement's calibration: the exact curve with the recorded constants gives the truth to
1e-6 K, the Measurement's band model to within the fit error the import reports.
"""

from __future__ import annotations

import io
import json
import shutil
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from metafovea.measurement import Measurement
from metafovea.reconstruct.deconvolve import temperatures
from metafovea.recordings import PlanckConstants, SceneParameters, read_recording
from metafovea.recordings.flir import stamp_times

Image = pytest.importorskip("PIL.Image")

#: what the files hold, as float32 (the format's type; O is an int32)
PLANCK = {"R1": float(np.float32(21106.77)), "R2": float(np.float32(0.012545258)), "B": float(np.float32(1501.0)),
          "F": float(np.float32(1.0)), "O": -7340.0}
SCENE = {k: float(np.float32(v)) for k, v in {
    "emissivity": 0.95, "distance_m": 5.0, "reflected_k": 293.15, "atmosphere_k": 295.15, "window_k": 296.15,
    "window_transmission": 0.9, "humidity": 0.45, "alpha1": 0.006569, "alpha2": 0.01262, "beta1": -0.002276,
    "beta2": -0.00667, "x": 1.9}.items()}
H, W = 48, 64
BAND = ("--band-um", 7.5, 13.5)


# ---------------------------------------------------------------------------------------------------------------
# FLIR's model, written out here (the truth)
# ---------------------------------------------------------------------------------------------------------------
def _counts(t):
    return PLANCK["R1"] / (PLANCK["R2"] * (np.exp(PLANCK["B"] / np.asarray(t, dtype=np.float64)) - PLANCK["F"])) \
        - PLANCK["O"]


def _tau():
    s = SCENE
    tc = s["atmosphere_k"] - 273.15
    h2o = s["humidity"] * np.exp(1.5587 + 0.06939 * tc - 0.00027816 * tc ** 2 + 0.00000068455 * tc ** 3)
    d = np.sqrt(s["distance_m"] / 2)
    return s["x"] * np.exp(-d * (s["alpha1"] + s["beta1"] * np.sqrt(h2o))) \
        + (1 - s["x"]) * np.exp(-d * (s["alpha2"] + s["beta2"] * np.sqrt(h2o)))


def flir_kelvin(raw):
    """The object temperature (K) of raw counts: the raw value less the reflected, air and window terms, each
    divided by what attenuates the object, then the Planck curve inverted."""
    s, tau = SCENE, _tau()
    e, tw = s["emissivity"], s["window_transmission"]
    obj = (np.asarray(raw, dtype=np.float64) / (e * tau * tw * tau)
           - (1 - e) / e * _counts(s["reflected_k"])
           - (1 - tau) / (e * tau) * _counts(s["atmosphere_k"])
           - (1 - tw) / (e * tau * tw) * _counts(s["window_k"])
           - (1 - tau) / (e * tau * tw * tau) * _counts(s["atmosphere_k"]))
    return PLANCK["B"] / np.log(PLANCK["R1"] / (PLANCK["R2"] * (obj + PLANCK["O"])) + PLANCK["F"])


def raw_of(t_obj):
    """uint16 counts of an object at ``t_obj`` K (the inverse of :func:`flir_kelvin`, rounded)."""
    s, tau = SCENE, _tau()
    e, tw = s["emissivity"], s["window_transmission"]
    raw = (e * tau * tau * tw * _counts(t_obj) + (1 - e) * tau * tau * tw * _counts(s["reflected_k"])
           + (1 - tau) * tau * tw * _counts(s["atmosphere_k"]) + (1 - tw) * tau * _counts(s["window_k"])
           + (1 - tau) * _counts(s["atmosphere_k"]))
    return np.round(raw).astype(np.uint16)


def scene_k(seed=0):
    """An object between 290 and 330 K: a ramp, a disc and a little texture."""
    y, x = np.mgrid[0:H, 0:W]
    t = 290.0 + 30.0 * x / (W - 1) + 10.0 * ((x - 40) ** 2 + (y - 20) ** 2 < 100)
    return t + np.random.default_rng(seed).uniform(-0.5, 0.5, (H, W))


# ---------------------------------------------------------------------------------------------------------------
# The writer (ExifTool, Image::ExifTool::FLIR: FFF header, record directory, RawData, CameraInfo; APP1 segments)
# ---------------------------------------------------------------------------------------------------------------
def camera_info(stamp_s=1_700_000_000.25, frame_rate=30, order="<"):
    """A CameraInfo record (type 0x20); byte order flag 0x0002 first, fields at ExifTool's offsets."""
    b = bytearray(0x480)
    s = SCENE

    def put(fmt, at, *v):
        struct.pack_into(order + fmt, b, at, *v)

    put("HHH", 0x00, 2, W, H)
    put("fffff", 0x20, s["emissivity"], s["distance_m"], s["reflected_k"], s["atmosphere_k"], s["window_k"])
    put("f", 0x34, s["window_transmission"])
    put("f", 0x3C, s["humidity"])
    put("fff", 0x58, PLANCK["R1"], PLANCK["B"], PLANCK["F"])
    put("fffff", 0x70, s["alpha1"], s["alpha2"], s["beta1"], s["beta2"], s["x"])
    b[0xD4:0xD4 + 9] = b"synthetic"  # CameraModel
    put("if", 0x308, int(PLANCK["O"]), PLANCK["R2"])
    secs = int(stamp_s)
    put("IIh", 0x384, secs, int(round((stamp_s - secs) * 1000)), 0)  # DateTimeOriginal: s, ms, time zone
    put("H", 0x464, frame_rate)
    return bytes(b)


def raw_data(counts, kind="le"):
    """A RawData record (type 0x01): a 0x20-byte header (byte order flag, width, height) and the image: 16-bit
    little- or big-endian counts, or a PNG of byte-swapped counts (as FLIR's cameras write it)."""
    order = ">" if kind == "be" else "<"
    head = bytearray(0x20)
    struct.pack_into(order + "HHH", head, 0, 2, counts.shape[1], counts.shape[0])
    struct.pack_into(order + "HH", head, 12, counts.shape[1] - 1, counts.shape[0] - 1)
    if kind == "png":
        buf = io.BytesIO()
        Image.fromarray(counts.astype(np.uint16).byteswap()).save(buf, format="PNG")
        return bytes(head) + buf.getvalue()
    if kind == "jpeg-ls":  # a compressed frame (a JPEG-LS stream's start and SOF55 markers are enough here)
        return bytes(head) + b"\xff\xd8\xff\xf7" + bytes(64)
    return bytes(head) + counts.astype(order + "u2").tobytes()


def fff(records, order="<", entries=14):
    """An FFF file: the 0x40-byte header, the record directory (32 bytes an entry; the records, then empty
    entries up to ``entries``, as a FLIR i7 writes 14), the records. (flyr reads directory entry ``i`` at byte
    ``32 i`` of the FFF data rather than of the directory: harmless with a camera's trailing empty entries.)"""
    at = 0x40 + 32 * entries
    directory = b""
    for rtype, subtype, data in records:
        directory += struct.pack(order + "HHIIIIIII", rtype, subtype, 0x64, 1, at, len(data), 0, 0, 0)
        at += len(data)
    directory += bytes(32 * (entries - len(records)))
    header = struct.pack(order + "4s16sIIIIH7HIII", b"FFF\0", b"metafovea test", 100, 0x40, entries, 2, 0,
                         *([0] * 7), 0, 0, 0)
    return header + directory + b"".join(d for _, _, d in records)


def frame(counts, kind="le", order="<", **info):
    subtype = {"be": 1, "le": 2, "png": 3, "jpeg-ls": 2}[kind]
    return fff([(0x01, subtype, raw_data(counts, kind)), (0x20, 1, camera_info(**info))], order)


def radiometric_jpeg(counts, kind="png", chunk=4000):
    """A JPEG (an 8-bit picture written by Pillow) with the FFF data (big-endian header, as FLIR's APP1) split
    into APP1 segments: "FLIR\\0", 1, the chunk's index, the last index."""
    data = frame(counts, kind, order=">")
    chunks = [data[i:i + chunk] for i in range(0, len(data), chunk)]
    segments = b"".join(b"\xff\xe1" + struct.pack(">H", 10 + len(c)) + b"FLIR\0" + bytes([1, i, len(chunks) - 1]) + c
                        for i, c in enumerate(chunks))
    buf = io.BytesIO()
    Image.fromarray(np.zeros((12, 16), np.uint8)).save(buf, format="JPEG")
    jpg = buf.getvalue()
    return jpg[:2] + segments + jpg[2:]


def seq(frames_counts, stamps_s, frame_rate=30):
    return b"".join(frame(c, stamp_s=t, frame_rate=frame_rate) for c, t in zip(frames_counts, stamps_s))


# ---------------------------------------------------------------------------------------------------------------
# The writer against ExifTool, the readers' own conversions against the formula
# ---------------------------------------------------------------------------------------------------------------
def _exiftool():
    flirpy = pytest.importorskip("flirpy", reason="flirpy (metafovea[flir]) ships ExifTool, the format's reference")
    tool = Path(flirpy.__file__).parent / "bin" / "exiftool"
    if shutil.which("perl") is None or not tool.is_file():
        pytest.skip("ExifTool needs perl and flirpy's copy of it (bin/exiftool)")
    return tool


@pytest.mark.parametrize("suffix", [".jpg", ".fff", ".seq"])
def test_exiftool_reads_the_written_files(tmp_path, suffix):
    """ExifTool, the reference reader of the format, finds in each written file the constants, the object
    parameters and the raw image's size that were written (the test's files are what the format says)."""
    tool = _exiftool()
    raw = raw_of(scene_k())
    path = tmp_path / f"x{suffix}"
    path.write_bytes({".jpg": lambda: radiometric_jpeg(raw), ".fff": lambda: frame(raw),
                      ".seq": lambda: seq([raw, raw], [1e9, 1e9 + 1 / 30])}[suffix]())
    out = subprocess.run(["perl", str(tool), "-j", "-n", str(path)], capture_output=True, text=True, timeout=60)
    tags = json.loads(out.stdout)[0]
    assert tags["RawThermalImageWidth"] == W and tags["RawThermalImageHeight"] == H, tags
    for tag, key in (("PlanckR1", "R1"), ("PlanckR2", "R2"), ("PlanckB", "B"), ("PlanckF", "F"), ("PlanckO", "O")):
        assert tags[tag] == pytest.approx(PLANCK[key], rel=1e-6), tag
    assert tags["Emissivity"] == pytest.approx(SCENE["emissivity"], rel=1e-6)
    assert tags["ReflectedApparentTemperature"] == pytest.approx(SCENE["reflected_k"] - 273.15, abs=1e-4)
    assert tags["AtmosphericTemperature"] == pytest.approx(SCENE["atmosphere_k"] - 273.15, abs=1e-4)
    assert tags["ObjectDistance"] == pytest.approx(SCENE["distance_m"]) and tags["FrameRate"] == 30


def test_the_readers_own_conversions_give_the_formula():
    """flyr's kelvin (a JPEG) and flirpy's raw2temp (an FFF frame) agree with the formula written here (flirpy's
    within 0.01 K: it reads the temperatures in Celsius with 273.14)."""
    flyr = pytest.importorskip("flyr", reason="flyr reads FLIR JPEGs (metafovea[flir])")
    pytest.importorskip("flirpy", reason="flirpy reads FLIR FFF/SEQ files (metafovea[flir])")
    from flirpy.io.fff import Fff
    from flirpy.util.raw import raw2temp

    raw = raw_of(scene_k())
    truth = flir_kelvin(raw)
    assert np.max(np.abs(truth - scene_k())) < 0.02  # one count is ~0.01-0.02 K here
    np.testing.assert_allclose(flyr.unpack(io.BytesIO(radiometric_jpeg(raw))).kelvin, truth, atol=1e-3)
    f = Fff(frame(raw) + bytes(4096))  # (flirpy takes bytes shorter than 4096 for a file name)
    np.testing.assert_allclose(raw2temp(f.get_image(), f.meta) + 273.15, truth, atol=0.01)


# ---------------------------------------------------------------------------------------------------------------
# metafovea's reader and import
# ---------------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("kind", ["png", "le"])
def test_jpeg_counts_constants_and_kelvin(tmp_path, kind):
    """A radiometric JPEG (raw counts as PNG or as 16-bit data, split over several APP1 segments): the counts as
    written, the file's constants, and the object temperature through calibration's one Planck inversion to 1e-6 K
    of the formula."""
    pytest.importorskip("flyr", reason="flyr reads FLIR JPEGs (metafovea[flir])")
    raw = raw_of(scene_k())
    path = tmp_path / "still.jpg"
    path.write_bytes(radiometric_jpeg(raw, kind))
    rec = read_recording(path)
    assert rec.format == "flir" and rec.frames.dtype == np.uint16 and rec.frames.shape == (1, H, W)
    np.testing.assert_array_equal(rec.frames[0], raw)
    assert rec.planck == pytest.approx(PLANCK, rel=1e-7)
    assert {k: rec.scene[k] for k in SCENE} == pytest.approx(SCENE, rel=1e-5)
    planck = PlanckConstants(**rec.planck)
    g, c = SceneParameters(**rec.scene).affine(planck)
    np.testing.assert_allclose(planck.temperature((rec.frames[0] - c) / g), flir_kelvin(raw), atol=1e-5)
    assert rec.attrs["reader"].startswith("flyr ")


def test_import_jpeg_writes_a_measurement_with_the_files_constants(tmp_path, cli):
    """``metafovea import still.jpg --out m.npz``: a Measurement of the counts whose metadata records the file's
    constants and object parameters (and where they came from) and gives the object's temperature within the
    band model's reported fit error."""
    pytest.importorskip("flyr", reason="flyr reads FLIR JPEGs (metafovea[flir])")
    raw = raw_of(scene_k())
    path = tmp_path / "still.jpg"
    path.write_bytes(radiometric_jpeg(raw))
    rc, out, err = cli("import", path, "--out", tmp_path / "m.npz", *BAND, "--json")
    assert rc == 0, err
    s = json.loads(out)
    assert s["frames"] == 1 and s["calibration"]["method"] == "planck"
    m = Measurement.load(tmp_path / "m.npz")
    np.testing.assert_array_equal(m.frames[0], raw.astype(np.float32))  # the counts, not temperatures
    cal = m.meta["calibration"]
    assert {k: cal["planck"][k] for k in PLANCK} == pytest.approx(PLANCK, rel=1e-7)
    assert "still.jpg" in cal["planck"]["from"] and "still.jpg" in cal["scene"]["from"]
    assert {k: cal["scene"][k] for k in SCENE} == pytest.approx(SCENE, rel=1e-5)
    assert m.meta["source"]["attrs"]["reader"].startswith("flyr ")
    truth = flir_kelvin(raw)
    exact = PlanckConstants(**{k: cal["planck"][k] for k in PLANCK}).temperature(
        (m.frames[0] - cal["scene"]["offset_counts"]) / cal["scene"]["gain"])
    np.testing.assert_allclose(exact, truth, atol=1e-5)
    t1, t2 = temperatures((m.frames[0], m.frames[0]), m.meta["dark_dn"], m.meta)
    fit = s["calibration"]["fit_max_error_k"]
    assert 0 < fit < 0.3
    assert np.max(np.abs(t1 - truth)) <= fit + 5e-3 and np.max(np.abs(t2 - truth)) <= fit + 5e-3


def test_seq_frames_times_dropped_frame_and_kelvin(tmp_path, cli):
    """A SEQ of 30 Hz frames stamped to the millisecond (33 and 34 ms steps), one frame missing: the frames as
    written, times on the 1/30 s grid, one dropped frame reported, the temperatures within the fit error."""
    pytest.importorskip("flirpy", reason="flirpy reads FLIR FFF/SEQ files (metafovea[flir])")
    k = np.array([0, 1, 2, 3, 5, 6, 7, 8])
    raws = [raw_of(scene_k(seed=int(i))) for i in k]
    stamps = 1_700_000_000.0 + np.round(k / 30.0 * 1000) / 1000
    path = tmp_path / "rec.seq"
    path.write_bytes(seq(raws, stamps))
    rec = read_recording(path)
    np.testing.assert_array_equal(rec.frames, np.stack(raws))
    np.testing.assert_allclose(rec.times_s, k / 30.0, atol=1e-12)
    assert "30 Hz grid" in rec.times_from and rec.attrs["reader"].startswith("flirpy ")
    rc, out, err = cli("import", path, *BAND, "--json")
    assert rc == 0, err
    s = json.loads(out)
    assert s["frames"] == 8 and s["n_dropped"] == 1 and s["uniform_timing"]
    assert s["frame_rate_hz"] == pytest.approx(30.0)
    m = Measurement.load(tmp_path / "rec.npz")
    t1, _ = temperatures((m.frames, m.frames), m.meta["dark_dn"], m.meta)
    assert np.max(np.abs(t1 - flir_kelvin(np.stack(raws)))) <= s["calibration"]["fit_max_error_k"] + 5e-3


def test_fff_with_big_endian_counts(tmp_path):
    """An FFF frame whose raw record is big-endian (its byte-order flag reads 0x0200 little-endian): the counts
    as written; the constants and object parameters as written."""
    pytest.importorskip("flirpy", reason="flirpy reads FLIR FFF/SEQ files (metafovea[flir])")
    raw = raw_of(scene_k())
    path = tmp_path / "one.fff"
    path.write_bytes(frame(raw, "be"))
    rec = read_recording(path)
    np.testing.assert_array_equal(rec.frames[0], raw)
    assert rec.times_s.tolist() == [0.0] and rec.planck == pytest.approx(PLANCK, rel=1e-7)
    assert {k: rec.scene[k] for k in SCENE} == pytest.approx(SCENE, rel=1e-6)  # kelvin as stored, not via Celsius


def test_stamp_times():
    """Millisecond stamps go on the frame-rate grid when within 1.5 ms of it; a 5 ms jitter stays as stamped;
    stamps that do not increase give the rate's times, or none without a rate."""
    k = np.arange(6)
    t, how = stamp_times(100.0 + np.round(k / 30 * 1000) / 1000, 30.0)
    np.testing.assert_allclose(t, k / 30)
    assert "grid" in how
    jitter = k / 30 + np.array([0, 0.005, 0, 0, 0, 0])
    t, how = stamp_times(jitter, 30.0)
    np.testing.assert_allclose(t, jitter)
    assert "stamps" in how
    t, how = stamp_times(np.zeros(6), 30.0)
    np.testing.assert_allclose(t, k / 30)
    assert "frame rate" in how
    assert stamp_times(np.zeros(6), None) == (None, None)


# ---------------------------------------------------------------------------------------------------------------
# What is not read: one line naming the file and what to do
# ---------------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize(("suffix", "package"), [(".jpg", "flyr"), (".seq", "flirpy")])
def test_a_missing_reader_is_one_line_with_the_install(tmp_path, cli, monkeypatch, suffix, package):
    path = tmp_path / f"x{suffix}"
    path.write_bytes(radiometric_jpeg(raw_of(scene_k())) if suffix == ".jpg" else frame(raw_of(scene_k())))
    for name in [m for m in sys.modules if m == package or m.startswith(package + ".")] + [package]:
        monkeypatch.setitem(sys.modules, name, None)  # import of it raises ImportError
    rc, out, err = cli("import", path, "--out", tmp_path / "m.npz")
    lines = err.strip().splitlines()
    assert rc == 2 and len(lines) == 1, err
    assert str(path) in lines[0] and 'pip install "metafovea[flir]"' in lines[0]
    assert not (tmp_path / "m.npz").exists()


@pytest.mark.parametrize("name", ["rec.irb", "rec.csq", "rec_csq_frames.seq"])
def test_unsupported_formats_say_what_to_export(tmp_path, cli, name):
    """InfraTec's IRB and FLIR's CSQ (by suffix), or a SEQ whose frames hold a compressed (JPEG-LS) stream: one
    line naming the file and the camera software's TIFF/MAT export."""
    path = tmp_path / name
    if name.endswith(".seq"):
        pytest.importorskip("flirpy", reason="flirpy reads FLIR FFF/SEQ files (metafovea[flir])")
        path.write_bytes(frame(raw_of(scene_k()), "jpeg-ls"))
    else:
        path.write_bytes(b"\0" * 1024)
    rc, out, err = cli("import", path)
    lines = err.strip().splitlines()
    assert rc == 2 and len(lines) == 1, err
    assert str(path) in lines[0] and "TIFF" in lines[0] and "MAT" in lines[0], lines[0]


def test_a_camera_written_jpeg_whose_image_was_stripped(tmp_path, cli):
    """ExifTool's test image of a FLIR i7 (shipped with flirpy's copy of ExifTool): its constants are a camera's,
    its raw image an 8 x 8 RGB placeholder (ExifTool strips the pictures of its test files). The import refuses it
    in one line naming the file, nothing written."""
    flirpy = pytest.importorskip("flirpy", reason="flirpy (metafovea[flir]) ships ExifTool and its test images")
    pytest.importorskip("flyr", reason="flyr reads FLIR JPEGs (metafovea[flir])")
    real = Path(flirpy.__file__).parent / "bin" / "t" / "images" / "FLIR.jpg"
    if not real.is_file():
        pytest.skip(f"this flirpy ships no {real.name} in its ExifTool copy")
    path = tmp_path / "FLIR_i7.jpg"
    shutil.copy(real, path)
    rc, out, err = cli("import", path)
    lines = err.strip().splitlines()
    assert rc == 2 and len(lines) == 1 and str(path) in lines[0] and "flyr" in lines[0], err
    assert not (tmp_path / "FLIR_i7.npz").exists()
