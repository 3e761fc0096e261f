"""The HTML report of a run folder, and its check in a real headless browser.

:func:`write_report` writes ``report.html`` beside its figures (relative links, no network, no external assets), so
the folder can be zipped, mailed or served as it is. The page carries a few lines of script that, once the page has
loaded, count the images that decoded (``complete`` and a natural width > 0), write the counts into ``<body>``'s
``data-images-ok`` / ``data-images-total`` attributes and show a red banner naming any image that did not render.
:func:`check_in_browser` loads the page in headless Chromium (``--dump-dom``) and reads those attributes back: the
page loads, and every image renders.
"""

from __future__ import annotations

import html
import os
import re
import shutil
import subprocess
import tempfile
from pathlib import Path
from typing import NamedTuple

from bayestouch.errors import BadInput, check_bool, check_path
from bayestouch.io.files import write_text

__all__ = ["Table", "Figure", "write_report", "check_in_browser", "BrowserCheck", "find_browser"]


class Table(NamedTuple):
    """A table of the report: ``caption``, ``header`` (column names) and ``rows`` (lists of cells, already text)."""

    caption: str
    header: list
    rows: list


class Figure(NamedTuple):
    """A figure of the report: ``file`` (a name inside the report's folder) and its ``caption``."""

    file: str
    caption: str


_STYLE = """
body { font-family: system-ui, sans-serif; max-width: 1180px; margin: 2em auto; padding: 0 1em; color: #222; }
h1 { font-size: 1.6em; } h2 { font-size: 1.25em; margin-top: 1.8em; border-bottom: 1px solid #ddd; }
table { border-collapse: collapse; margin: 0.6em 0 1.2em; font-size: 0.9em; }
th, td { border: 1px solid #ccc; padding: 0.25em 0.6em; text-align: right; }
th { background: #f3f3f3; } td:first-child, th:first-child { text-align: left; }
caption { text-align: left; font-weight: 600; padding-bottom: 0.3em; }
figure { margin: 1em 0 2em; } figure img { max-width: 100%; border: 1px solid #eee; }
figcaption { font-size: 0.9em; color: #444; margin-top: 0.3em; }
.note { background: #f7f7f2; border-left: 4px solid #c9b458; padding: 0.5em 1em; }
.ok { color: #176b2c; font-weight: 600; } .bad { color: #a11; font-weight: 600; }
#broken { display: none; background: #fdd; border: 1px solid #a11; padding: 0.5em 1em; }
"""

_SCRIPT = """
window.addEventListener("load", function () {
  var imgs = Array.prototype.slice.call(document.images);
  var bad = imgs.filter(function (i) { return !(i.complete && i.naturalWidth > 0); });
  document.body.setAttribute("data-images-total", String(imgs.length));
  document.body.setAttribute("data-images-ok", String(imgs.length - bad.length));
  document.body.setAttribute("data-images-broken", bad.map(function (i) { return i.getAttribute("src"); }).join(" "));
  if (bad.length) {
    var box = document.getElementById("broken");
    var names = bad.map(function (i) { return i.getAttribute("src"); });
    box.textContent = "Images that did not render: " + names.join(", ");
    box.style.display = "block";
  }
});
"""


def _table(t: Table) -> str:
    head = "".join(f"<th>{html.escape(str(h))}</th>" for h in t.header)
    body = "".join("<tr>" + "".join(f"<td>{c}</td>" for c in row) + "</tr>" for row in t.rows)
    return f"<table><caption>{html.escape(t.caption)}</caption><tr>{head}</tr>{body}</table>"


def write_report(
    out, *, title: str, intro: str, sections: list, files: list | None = None, overwrite: bool = False
) -> Path:
    """Write ``out/report.html`` (atomically: a reader sees the old page or the new one, never half of one).

    Parameters
    ----------
    out : path-like
        The run folder; every :class:`Figure` file must already be there.
    title : str
    intro : str
        HTML shown under the title (trusted: written by this package).
    sections : list of (heading, items)
        ``items`` is a list of :class:`Table`, :class:`Figure` or str (trusted HTML paragraphs).
    files : list of str, optional
        Names of files in ``out`` to list with links.
    overwrite : bool
        Replace a ``report.html`` already in ``out``; without it an earlier page is refused, not replaced.

    Returns
    -------
    Path of ``report.html``.

    Raises
    ------
    FileNotFoundError
        A figure's file is missing.
    BadInput
        ``out/report.html`` exists and ``overwrite`` is false.
    """
    check_path(out, "out")
    check_bool(overwrite, "overwrite")
    _check_page(title, intro, sections, files)
    out = Path(out)
    if not out.is_dir():
        raise BadInput(f"write_report: out {out} is not a folder; expected the run folder that holds the figures")
    page_path = out / "report.html"
    if page_path.is_dir():
        raise BadInput(f"write_report: {page_path} is a folder; expected a file name free for the page")
    if not overwrite and page_path.exists():
        raise BadInput(f"write_report: {page_path} exists; pass overwrite=True to replace it")
    parts = [f"<h1>{html.escape(title)}</h1>", '<div id="broken"></div>', intro]
    for heading, items in sections:
        parts.append(f"<h2>{html.escape(heading)}</h2>")
        for it in items:
            if isinstance(it, Table):
                parts.append(_table(it))
            elif isinstance(it, Figure):
                if not (out / it.file).is_file():
                    raise FileNotFoundError(f"report: figure {it.file} is not in {out}")
                src = html.escape(it.file, quote=True)
                parts.append(
                    f'<figure><img src="{src}" alt="{html.escape(it.caption, quote=True)}">'
                    f"<figcaption>{html.escape(it.caption)}</figcaption></figure>"
                )
            else:
                parts.append(str(it))
    if files:
        links = "".join(
            f'<li><a href="{html.escape(f, quote=True)}">{html.escape(f)}</a></li>' for f in files if (out / f).exists()
        )
        parts.append(f"<h2>Files</h2><ul>{links}</ul>")
    page = (
        f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8"><title>{html.escape(title)}</title>'
        f"<style>{_STYLE}</style><script>{_SCRIPT}</script></head>\n<body>\n" + "\n".join(parts) + "\n</body></html>\n"
    )
    return write_text(page_path, page)


def _check_page(title, intro, sections, files) -> None:
    """Refuse (:class:`BadInput`, one line) a title or intro that is not text, files that are not names, sections
    not in the form ``[(heading, [Table | Figure | str, ...]), ...]``, and a table row longer or shorter than its
    header."""
    for name, value in (("title", title), ("intro", intro)):
        if not isinstance(value, str):
            raise BadInput(f"write_report: {name} must be a str, got {type(value).__name__}")
    if files is not None and not (isinstance(files, list | tuple) and all(isinstance(f, str) for f in files)):
        raise BadInput("write_report: files must be a list of file names (str) in out")
    if not isinstance(sections, list | tuple):
        raise BadInput(f"write_report: sections must be a list of (heading, items), got {type(sections).__name__}")
    for k, sec in enumerate(sections):
        if not (isinstance(sec, list | tuple) and len(sec) == 2 and isinstance(sec[0], str)):
            raise BadInput(f"write_report: sections[{k}] must be a (heading, items) pair, got {sec!r:.60}")
        if not isinstance(sec[1], list | tuple):
            raise BadInput(f"write_report: sections[{k}] items must be a list, got {type(sec[1]).__name__}")
        for it in sec[1]:
            if isinstance(it, Table):
                bad = [i for i, row in enumerate(it.rows) if len(row) != len(it.header)]
                if bad:
                    raise BadInput(
                        f"write_report: table {it.caption!r} row {bad[0]} has {len(it.rows[bad[0]])} cells for "
                        f"{len(it.header)} columns"
                    )
            elif not isinstance(it, Figure | str):
                raise BadInput(
                    f"write_report: sections[{k}] holds a {type(it).__name__}; expected Table, Figure or str"
                )


class BrowserCheck(NamedTuple):
    """What the headless browser saw: images that rendered, images in all, the ``src`` of broken ones, and the
    page's title."""

    images_ok: int
    images_total: int
    broken: list
    title: str


def find_browser() -> str | None:
    """Path of a Chromium-family browser on this machine (``chromium``, ``chromium-browser``, ``google-chrome``), or
    None."""
    for name in ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable"):
        path = shutil.which(name)
        if path:
            return path
    return None


def check_in_browser(page, *, browser: str | None = None, timeout_s: float = 60.0) -> BrowserCheck:
    """Load ``page`` (an HTML file) in headless Chromium and report which images rendered.

    Raises
    ------
    FileNotFoundError
        No page, or no browser (install Debian's ``chromium``).
    RuntimeError
        The browser failed, or the page never ran its load handler.
    """
    page = Path(page).resolve()
    if not page.is_file():
        raise FileNotFoundError(f"report: {page} does not exist")
    browser = browser or find_browser()
    if browser is None:
        raise FileNotFoundError("no headless browser: install Debian's chromium (apt-get install chromium)")
    with tempfile.TemporaryDirectory(dir="/tmp" if os.path.isdir("/tmp") else None) as profile:
        cmd = [
            browser,
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-quic",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--allow-file-access-from-files",
            f"--user-data-dir={profile}",
            "--virtual-time-budget=5000",
            "--dump-dom",
            page.as_uri(),
        ]
        # a short TMPDIR: Chromium's singleton socket path must fit in 108 bytes
        env = {**os.environ, "TMPDIR": "/tmp"} if os.path.isdir("/tmp") else None
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s, check=False, env=env)
    if proc.returncode != 0:
        raise RuntimeError(f"{browser} exited with {proc.returncode}: {proc.stderr.strip()[-500:]}")
    dom = proc.stdout
    body = re.search(r"<body([^>]*)>", dom)
    attrs = dict(re.findall(r'(data-images-[a-z]+)="([^"]*)"', body.group(1))) if body else {}
    if "data-images-total" not in attrs:
        raise RuntimeError(f"{page.name}: the page's load handler did not run (no data-images-total on <body>)")
    title = re.search(r"<title>(.*?)</title>", dom, re.S)
    return BrowserCheck(
        int(attrs["data-images-ok"]),
        int(attrs["data-images-total"]),
        attrs.get("data-images-broken", "").split(),
        html.unescape(title.group(1)) if title else "",
    )
