"""The documentation site in a real browser: `mkdocs build --strict`, then every page loaded in
headless Chromium over a local HTTP server: no broken link or image, no console error, and the
home page shows a leaderboard table and the RMSAE-against-T60 figure; in a 1280 px window no
table runs past the window's right edge.

Needs the Debian `chromium` package (`.ci/run` installs it when missing); without it the test
skips and says so. Chromium is driven through the DevTools protocol over a pipe
(``--remote-debugging-pipe``: JSON messages separated by NUL bytes on file descriptors 3 and 4),
so no Python browser package is needed. ``DOABENCH_SITE_SCREENSHOT=FILE.png`` saves a screenshot
of the home page.
"""
from __future__ import annotations

import functools
import http.server
import json
import os
import re
import select
import shutil
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.request
from pathlib import Path
from urllib.parse import urldefrag, urlparse

import pytest

ROOT = Path(__file__).resolve().parents[1]
BROWSERS = ("chromium", "chromium-browser", "google-chrome")
WINDOW_WIDTH = 1280


def _browser() -> str | None:
    return next((path for path in map(shutil.which, BROWSERS) if path), None)


class DevTools:
    """A headless Chromium driven through the DevTools protocol on a pipe."""

    def __init__(self, browser: str, profile: Path, timeout: float = 60.0) -> None:
        self.timeout = timeout
        to_r, self._to_w = os.pipe()
        self._from_r, from_w = os.pipe()

        def at_3_and_4() -> None:  # the protocol's file descriptors in the child
            os.dup2(to_r, 3)
            os.dup2(from_w, 4)

        args = [browser, "--headless=new", "--remote-debugging-pipe", "--no-sandbox", "--disable-gpu",
                "--disable-dev-shm-usage", "--no-first-run", "--no-default-browser-check", "--disable-extensions",
                "--disable-background-networking", "--disable-component-update", "--disable-sync",
                "--hide-scrollbars", "--window-size=1280,1600", f"--user-data-dir={profile}", "about:blank"]
        self.proc = subprocess.Popen(args, pass_fds=(3, 4), preexec_fn=at_3_and_4, stdin=subprocess.DEVNULL,
                                     stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        os.close(to_r)
        os.close(from_w)
        self._buffer = b""
        self._next = 0
        self.events: list[dict] = []

    def close(self) -> None:
        try:
            self.send("Browser.close", wait=False)
        except OSError:
            pass
        try:
            self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        for fd in (self._to_w, self._from_r):
            try:
                os.close(fd)
            except OSError:
                pass

    def _read(self, deadline: float) -> dict:
        while b"\0" not in self._buffer:
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError("no answer from Chromium")
            ready, _, _ = select.select([self._from_r], [], [], left)
            if ready:
                chunk = os.read(self._from_r, 1 << 20)
                if not chunk:
                    raise RuntimeError("Chromium closed the DevTools pipe")
                self._buffer += chunk
        message, self._buffer = self._buffer.split(b"\0", 1)
        return json.loads(message)

    def send(self, method: str, params: dict | None = None, session: str | None = None, wait: bool = True) -> dict:
        self._next += 1
        message = {"id": self._next, "method": method, "params": params or {}}
        if session:
            message["sessionId"] = session
        os.write(self._to_w, json.dumps(message).encode() + b"\0")
        if not wait:
            return {}
        deadline = time.monotonic() + self.timeout
        while True:
            reply = self._read(deadline)
            if reply.get("id") == self._next:
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error']}")
                return reply.get("result", {})
            self.events.append(reply)

    def wait_event(self, method: str, session: str) -> dict:
        deadline = time.monotonic() + self.timeout
        for i, event in enumerate(self.events):
            if event.get("method") == method and event.get("sessionId") == session:
                return self.events.pop(i)
        while True:
            event = self._read(deadline)
            if event.get("method") == method and event.get("sessionId") == session:
                return event
            self.events.append(event)


def _errors(events: list[dict]) -> list[str]:
    """Console errors, uncaught exceptions, failed and 4xx/5xx requests among DevTools events."""
    out = []
    for e in events:
        m, p = e.get("method"), e.get("params") or {}
        if m == "Runtime.consoleAPICalled" and p.get("type") in ("error", "assert"):
            out.append("console: " + " ".join(str(a.get("value", a.get("description", ""))) for a in p.get("args", [])))
        elif m == "Runtime.exceptionThrown":
            details = p.get("exceptionDetails") or {}
            out.append(f"exception: {details.get('text')} "
                       f"{(details.get('exception') or {}).get('description', '')}".strip())
        elif m == "Log.entryAdded" and (p.get("entry") or {}).get("level") == "error":
            entry = p["entry"]
            out.append(f"log: {entry.get('text')} {entry.get('url', '')}")
        elif m == "Network.loadingFailed" and not p.get("canceled"):
            out.append(f"request failed: {p.get('errorText')}")
        elif m == "Network.responseReceived" and int((p.get("response") or {}).get("status", 200)) >= 400:
            out.append(f"HTTP {p['response']['status']}: {p['response'].get('url')}")
    return out


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    pytest.importorskip("mkdocs", reason="mkdocs is in the test extra: pip install -e '.[test]'")
    if _browser() is None:
        pytest.skip("no Chromium on this machine (Debian: apt-get install -y chromium; .ci/run installs it)")
    out = tmp_path_factory.mktemp("site")
    proc = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(out)], cwd=ROOT,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return out


@pytest.fixture(scope="module")
def server(site: Path):
    class Quiet(http.server.SimpleHTTPRequestHandler):
        def log_message(self, *args) -> None:
            pass

    httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), functools.partial(Quiet, directory=str(site)))
    thread = threading.Thread(target=httpd.serve_forever, daemon=True)
    thread.start()
    yield f"http://127.0.0.1:{httpd.server_address[1]}/"
    httpd.shutdown()
    httpd.server_close()


@functools.lru_cache(maxsize=None)
def _fetch(url: str) -> tuple[int, str]:
    try:
        with urllib.request.urlopen(url, timeout=30) as r:
            body = r.read()
            return r.status, body.decode("utf-8", "replace") if "html" in r.headers.get("Content-Type", "") else ""
    except urllib.error.HTTPError as exc:
        return exc.code, ""


def _pages(site: Path) -> list[str]:
    """Every page of the built site, relative to its root (``""`` is the home page)."""
    pages = []
    for path in sorted(site.rglob("index.html")):
        rel = path.parent.relative_to(site).as_posix()
        if rel.startswith(("search", "img", "css", "js", "fonts")):
            continue
        pages.append("" if rel == "." else rel + "/")
    return pages


def test_every_page_loads_without_errors_or_broken_links(site: Path, server: str, tmp_path: Path) -> None:
    pages = _pages(site)
    assert "" in pages and "leaderboards/sim-grid/" in pages and "model-cards/" in pages, pages
    browser = DevTools(_browser(), tmp_path / "profile")
    problems: dict[str, list[str]] = {}
    try:
        target = browser.send("Target.createTarget", {"url": "about:blank"})["targetId"]
        session = browser.send("Target.attachToTarget", {"targetId": target, "flatten": True})["sessionId"]
        for method in ("Page.enable", "Runtime.enable", "Log.enable", "Network.enable"):
            browser.send(method, session=session)
        # A 1280 px window (a laptop's): every table must end inside it, the leaderboards' last
        # column (the lag) included.
        browser.send("Emulation.setDeviceMetricsOverride", {"width": WINDOW_WIDTH, "height": 1600,
                                                            "deviceScaleFactor": 1, "mobile": False}, session=session)
        for page in pages:
            url = server + page
            browser.events.clear()
            browser.send("Page.navigate", {"url": url}, session=session)
            browser.wait_event("Page.loadEventFired", session)
            time.sleep(0.2)  # late console messages (scripts run after load)
            state = json.loads(browser.send("Runtime.evaluate", {"returnByValue": True, "expression": """
                JSON.stringify({
                  broken: Array.from(document.images).filter(i => !(i.complete && i.naturalWidth > 0)).map(i => i.src),
                  links: Array.from(document.querySelectorAll('a[href]')).map(a => a.href),
                  tables: Array.from(document.querySelectorAll('table')).map(t => t.innerText.slice(0, 300)),
                  images: Array.from(document.images).map(i => [i.src, i.naturalWidth]),
                  window: document.documentElement.clientWidth,
                  wide: Array.from(document.querySelectorAll('table'))
                    .map(t => [t.getBoundingClientRect().right, t.rows.length ? t.rows[0].innerText : ''])
                    .filter(([right]) => right > document.documentElement.clientWidth + 0.5),
                })"""}, session=session)["result"]["value"])
            if page == "" and os.environ.get("DOABENCH_SITE_SCREENSHOT"):
                shot = browser.send("Page.captureScreenshot", {"format": "png"}, session=session)["data"]
                import base64

                Path(os.environ["DOABENCH_SITE_SCREENSHOT"]).write_bytes(base64.b64decode(shot))
            found = _errors([e for e in browser.events if e.get("sessionId") == session])
            found += [f"broken image: {src}" for src in state["broken"]]
            assert state["window"] == WINDOW_WIDTH, state["window"]
            found += [f"table ends at {right:.0f} px, beyond the {WINDOW_WIDTH} px window: "
                      f"{' '.join(head.split())[:100]}" for right, head in state["wide"]]
            for link in state["links"]:
                base, fragment = urldefrag(link)
                if urlparse(link).netloc != urlparse(server).netloc:
                    continue  # outside the site: not reachable from a test machine
                status, html = _fetch(base)
                if status != 200:
                    found.append(f"broken link: {link} (HTTP {status})")
                elif fragment and html and not re.search(rf'id="{re.escape(fragment)}"', html):
                    found.append(f"broken anchor: {link}")
            if page == "":
                assert any("RMSAE all frames" in t and "cross3d:16x32" in t for t in state["tables"]), state["tables"]
                assert any("fig8-rmsae-all-vs-t60.png" in src and width > 0 for src, width in state["images"]), \
                    state["images"]
            if found:
                problems[page or "(home)"] = found
    finally:
        browser.close()
    assert not problems, json.dumps(problems, indent=1)
