"""The screenshot check that page and report tests rely on must tell a drawn page from
a blank one, in real headless Chromium."""
from browser import blank_reason, screenshot


def test_drawn_page_is_not_blank_and_white_page_is(tmp_path):
    drawn = tmp_path / "drawn.html"
    # Drawn by script, as the pages and reports are: the check must see what JS drew.
    drawn.write_text("<html><body style='margin:0'><canvas id=c width=400 height=300></canvas><script>"
                     "const g=document.getElementById('c').getContext('2d');"
                     "for(let i=0;i<20;i++){g.fillStyle=`hsl(${i*18},70%,50%)`;g.fillRect(i*20,i*10,60,60);}"
                     "</script></body></html>")
    white = tmp_path / "white.html"
    white.write_text("<html><body style='background:#fff'></body></html>")
    assert blank_reason(screenshot(drawn, tmp_path / "drawn.png", size=(400, 300))) is None
    assert blank_reason(screenshot(white, tmp_path / "white.png", size=(400, 300))) is not None
