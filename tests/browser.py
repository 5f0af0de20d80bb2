"""Headless Chromium for tests of pages and HTML reports.

One place that starts Debian's chromium (no browser is downloaded) and judges a
screenshot, so every page test looks at pixels the same way:

    from browser import screenshot, assert_not_blank
    png = screenshot("file:///.../report.html", tmp_path / "report.png")
    assert_not_blank(png)

Interactive tests (clicks, drags) drive the same binary through chromedriver; this
module only provides the binary's path (`CHROMIUM`) and the screenshot check.
"""
import pathlib
import shutil
import subprocess

from PIL import Image, ImageStat

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"


def screenshot(url, out_png, size=(1280, 900), wait_ms=2000, timeout=60):
    """Renders URL (http://, file://, or a path) and writes a PNG; returns its path.

    wait_ms is virtual time given to scripts before the picture is taken, so pages
    that draw from JavaScript (canvas, WebGL) are drawn first."""
    out_png = pathlib.Path(out_png)
    if "://" not in str(url):
        url = pathlib.Path(url).resolve().as_uri()
    args = [CHROMIUM, "--headless=new", "--no-sandbox", "--disable-gpu",
            "--use-gl=swiftshader", "--enable-unsafe-swiftshader",
            "--hide-scrollbars", "--no-first-run", "--disable-extensions",
            f"--window-size={size[0]},{size[1]}",
            f"--virtual-time-budget={wait_ms}",
            f"--screenshot={out_png}", str(url)]
    p = subprocess.run(args, capture_output=True, text=True, timeout=timeout)
    if p.returncode != 0 or not out_png.exists():
        raise AssertionError(f"chromium failed on {url} (exit {p.returncode}):\n{p.stderr[-2000:]}")
    return out_png


def blank_reason(png, min_colours=8, min_stddev=8.0):
    """Why the picture counts as blank, or None. Blank: nearly one colour (a white or
    black page, an error page with one line of text still passes only if it has
    several colours and contrast, so callers also check the page's own content)."""
    im = Image.open(png).convert("RGB")
    small = im.resize((min(im.width, 320), min(im.height, 240)))
    colours = small.getcolors(maxcolors=1 << 16)
    n = len(colours) if colours is not None else 1 << 16
    sd = max(ImageStat.Stat(im).stddev)
    if n < min_colours:
        return f"{png}: only {n} colours"
    if sd < min_stddev:
        return f"{png}: pixel standard deviation {sd:.1f} < {min_stddev}"
    return None


def assert_not_blank(png, **kw):
    reason = blank_reason(png, **kw)
    assert reason is None, reason
