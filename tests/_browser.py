"""Render an HTML page in a real browser engine and report what it shows.

Qt WebEngine (Chromium, from the ``PyQt6-WebEngine`` wheels of the development install)
loads the page headless (Qt's offscreen platform), runs its scripts and lays it out at a
laptop's window size; then the page's rendered DOM is read with JavaScript and the window is
saved as a PNG. Run as a script, in a process of its own (Qt wants its application on the
main thread, once per process)::

    python tests/_browser.py PAGE.html SHOT.png > dom.json

It prints one JSON object: ``loaded``, the window's ``width`` and ``height``, the page's
``text`` (``innerText``: what a reader sees), its ``headings`` (each ``h2`` with its text and
``top`` in pixels), the ``cards`` of the opening summary (value, label, top), the ``rows`` of
the first table (the cells' text), and its ``images`` (source, whether complete, natural
width).
"""

from __future__ import annotations

import json
import os
import sys

WIDTH, HEIGHT = 1280, 900
TIMEOUT_MS = 60_000

#: what the test reads of the rendered page
QUERY = """
(() => {
  const top = (e) => e.getBoundingClientRect().top + window.scrollY;
  const cards = [...document.querySelectorAll('.card')].map((c) => ({
    value: (c.querySelector('.v') || c).innerText.trim(),
    label: (c.querySelector('.k') || c).innerText.trim(),
    top: top(c),
  }));
  const table = document.querySelector('table');
  const cells = (r) => [...r.querySelectorAll('td')].map((d) => d.innerText.trim());
  const rows = table ? [...table.querySelectorAll('tr')].map(cells).filter((r) => r.length) : [];
  return JSON.stringify({
    width: window.innerWidth,
    height: window.innerHeight,
    text: document.body.innerText,
    headings: [...document.querySelectorAll('h2')].map((h) => ({text: h.innerText, top: top(h)})),
    cards: cards,
    rows: rows,
    images: [...document.images].map((i) => ({
      src: i.getAttribute('src'), complete: i.complete, width: i.naturalWidth})),
  });
})()
"""


def main(page: str, shot: str) -> None:
    os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
    # Chromium's sandbox needs user namespaces, which a container run as root lacks
    os.environ.setdefault("QTWEBENGINE_DISABLE_SANDBOX", "1")
    os.environ.setdefault("QTWEBENGINE_CHROMIUM_FLAGS", "--disable-gpu")
    from PyQt6.QtCore import QTimer, QUrl
    from PyQt6.QtWebEngineWidgets import QWebEngineView
    from PyQt6.QtWidgets import QApplication

    app = QApplication([sys.argv[0]])
    view = QWebEngineView()
    view.resize(WIDTH, HEIGHT)
    result: dict = {"loaded": False}

    def grab() -> None:
        view.grab().save(shot)
        app.quit()

    def read(dom: str) -> None:
        result.update(json.loads(dom))
        # one more frame, so that the screenshot shows the laid-out page
        QTimer.singleShot(300, grab)

    def loaded(ok: bool) -> None:
        result["loaded"] = ok
        view.page().runJavaScript(QUERY, read)

    view.loadFinished.connect(loaded)
    view.load(QUrl.fromLocalFile(os.path.abspath(page)))
    view.show()
    QTimer.singleShot(TIMEOUT_MS, app.quit)
    app.exec()
    print(json.dumps(result))


if __name__ == "__main__":
    main(*sys.argv[1:3])
