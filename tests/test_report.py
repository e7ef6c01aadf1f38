"""metafovea.report: the one figure-to-PNG helper, array images and the HTML page."""

import io

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from metafovea.report import HtmlReport, array_png, fig_to_png  # noqa: E402

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
