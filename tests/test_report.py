"""metafovea.report: the one figure-to-PNG helper, array images and the HTML page."""

import io

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pytest

from metafovea.report import HtmlReport, array_png, fig_to_png

PNG = b"\x89PNG\r\n\x1a\n"


def test_array_png_has_one_pixel_per_element_and_survives_nan():
    img = np.arange(12.0).reshape(3, 4)
    img[1, 2] = np.nan
    data = array_png(img)
    assert data[:8] == PNG
    back = plt.imread(io.BytesIO(data))
    assert back.shape[:2] == (3, 4)
    # monotone palette ends: the smallest and largest values map to different colours
    assert not np.allclose(back[0, 0], back[2, 3])


def test_fig_to_png_and_html_page(tmp_path):
    fig, ax = plt.subplots()
    ax.plot([0, 1], [1, 0])
    png = fig_to_png(fig, dpi=50)
    plt.close(fig)
    assert png[:8] == PNG
    rep = HtmlReport("a <title>")
    rep.heading("x & y")
    rep.table(["k", "v"], [["nan", float("nan")], ["pi", 3.14159265]])
    rep.image(png, "caption")
    page = rep.write(tmp_path / "r.html").read_text()
    assert page.startswith("<!DOCTYPE html>") and "a &lt;title&gt;" in page and "x &amp; y" in page
    assert "n/a" in page and "3.142" in page and page.count("data:image/png;base64,") == 1


def test_wide_tables_scroll_in_their_box_and_the_check_catches_a_page_that_does_not(tmp_path, browser_check):
    from metafovea.report import HtmlReport

    page = HtmlReport("wide")
    page.table([f"column number {j} (unit)" for j in range(30)], [[1.23456789 * j for j in range(30)]] * 3)
    page.verdict([{"stage": "s", "check": "c", "value": "1 dB", "reference": ">= 0 dB", "passed": True}])
    ok = page.write(tmp_path / "ok.html")
    browser_check(ok)
    # the same table without its scrolling box widens the page: the browser check must fail on it
    bad = tmp_path / "bad.html"
    bad.write_text(ok.read_text().replace('<div class="scroll">', "<div>"))
    with pytest.raises(AssertionError, match="overflows"):
        browser_check(bad)
    raw = tmp_path / "raw.html"
    raw.write_text(ok.read_text().replace("1 dB", "{'a': None}"))
    with pytest.raises(AssertionError, match="raw Python"):
        browser_check(raw)


def test_fmt_never_shows_a_repr():
    from metafovea.report import fmt

    assert fmt(None) == "-" and fmt(float("nan")) == "n/a" and fmt(True) == "yes"
    assert fmt({"identified": "calibration", "rank": 3}) == "identified calibration; rank 3"
    assert fmt(0.008850757730136834) == "0.00885" and fmt(2.5, "dB") == "2.5 dB"
