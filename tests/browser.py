"""Open a local HTML file in headless Chromium over the DevTools protocol, network off.

Uses tornado's websocket client (installed with dask.distributed), so no browser driver
package is needed. Returns what a reader would see at a 1280x900 window: each image's
natural and drawn size, the page's layout (document width and height, every table row's
drawn height, where the summary and its cards sit), every request the page made, console
errors and exceptions, and a screenshot of the first screen.
"""

from __future__ import annotations

import asyncio
import base64
import json
import shutil
import subprocess
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome")
WIDTH, HEIGHT = 1280, 900

# Runs in the page once it has loaded: the layout as measured by the browser itself.
_PROBE = """JSON.stringify((() => {
  const de = document.documentElement;
  const box = e => e.getBoundingClientRect();
  const rows = Array.from(document.querySelectorAll('tr')).map(r => ({
    height: box(r).height, width: box(r).width, text: r.innerText.slice(0, 120)}));
  const figures = Array.from(document.querySelectorAll('figure img')).map(i => ({
    width: box(i).width, height: box(i).height, alt: i.alt}));
  const s = document.getElementById('summary');
  const cards = s ? Array.from(s.querySelectorAll('.card')).map(c => ({
    top: box(c).top + window.scrollY, bottom: box(c).bottom + window.scrollY,
    text: c.innerText})) : [];
  return {
    scrollWidth: de.scrollWidth, clientWidth: de.clientWidth,
    innerWidth: window.innerWidth, innerHeight: window.innerHeight,
    scrollHeight: de.scrollHeight, rows: rows, figures: figures,
    summaryTop: s ? box(s).top + window.scrollY : null,
    summaryText: s ? s.innerText : '', cards: cards,
    firstSection: (document.querySelector('section') || {}).id || null,
    overflow: Array.from(document.querySelectorAll('body *')).filter(e =>
      box(e).right > window.innerWidth + 0.5 && !e.closest('.tablewrap')).slice(0, 5).map(e =>
      e.tagName + '.' + e.className + ' ' + Math.round(box(e).right) + ' ' +
      (e.innerText || '').slice(0, 60)),
    links: Array.from(document.querySelectorAll('a[href^="#"]')).map(a => a.getAttribute('href')),
    ids: Array.from(document.querySelectorAll('[id]')).map(e => e.id)};
})())"""


def find_chromium() -> str | None:
    for name in CHROMIUM_NAMES:
        path = shutil.which(name)
        if path:
            return path
    return None


@dataclass
class PageVisit:
    image_sizes: list[tuple[int, int]] = field(default_factory=list)
    requests: list[str] = field(default_factory=list)
    console_errors: list[str] = field(default_factory=list)
    screenshot: bytes = b""
    title: str = ""
    layout: dict = field(default_factory=dict)


def visit(
    html_file: Path,
    screenshot: Path,
    timeout: float = 60.0,
    scrolled: dict[str, Path] | None = None,
) -> PageVisit:
    """Load ``html_file`` and collect what the page did; ``screenshot`` is the first screen,
    ``scrolled`` maps a CSS selector to a screenshot taken with that element at the top."""
    from tornado.ioloop import IOLoop

    exe = find_chromium()
    if exe is None:
        raise RuntimeError("chromium not found")
    profile = Path(tempfile.mkdtemp(prefix="qsls-chromium-"))
    args = [
        exe,
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-quic",
        "--no-first-run",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--disable-extensions",
        "--proxy-server=127.0.0.1:9",  # network off: any http(s) request would fail
        "--host-resolver-rules=MAP * ~NOTFOUND",
        f"--window-size={WIDTH},{HEIGHT}",
        f"--user-data-dir={profile}",
        "--remote-debugging-port=0",
        "about:blank",
    ]
    proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        port_file = profile / "DevToolsActivePort"
        deadline = time.monotonic() + timeout
        while not (port_file.is_file() and len(port_file.read_text().splitlines()) >= 2):
            if time.monotonic() > deadline or proc.poll() is not None:
                raise RuntimeError("chromium did not start its DevTools endpoint")
            time.sleep(0.1)
        port, path = port_file.read_text().splitlines()[:2]
        url = f"ws://127.0.0.1:{port}{path}"
        return IOLoop.current().run_sync(
            lambda: _drive(url, Path(html_file).resolve().as_uri(), screenshot, scrolled or {}),
            timeout=timeout,
        )
    finally:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
        shutil.rmtree(profile, ignore_errors=True)


async def _drive(
    ws_url: str, page_url: str, screenshot: Path, scrolled: dict[str, Path]
) -> PageVisit:
    from tornado.websocket import websocket_connect

    conn = await websocket_connect(ws_url, max_message_size=256 * 1024 * 1024)
    visit_ = PageVisit()
    next_id = [0]
    events: list[dict] = []

    async def call(method: str, params: dict | None = None, session: str | None = None) -> dict:
        next_id[0] += 1
        msg = {"id": next_id[0], "method": method, "params": params or {}}
        if session:
            msg["sessionId"] = session
        await conn.write_message(json.dumps(msg))
        while True:
            raw = await conn.read_message()
            if raw is None:
                raise RuntimeError("DevTools connection closed")
            data = json.loads(raw)
            if data.get("id") == next_id[0]:
                if "error" in data:
                    raise RuntimeError(f"{method}: {data['error']}")
                return data.get("result", {})
            events.append(data)

    target = await call("Target.createTarget", {"url": "about:blank"})
    attached = await call(
        "Target.attachToTarget", {"targetId": target["targetId"], "flatten": True}
    )
    sid = attached["sessionId"]
    for domain in ("Page", "Runtime", "Network", "Log"):
        await call(f"{domain}.enable", session=sid)
    await call(
        "Emulation.setDeviceMetricsOverride",
        {"width": WIDTH, "height": HEIGHT, "deviceScaleFactor": 1, "mobile": False},
        session=sid,
    )
    await call("Page.navigate", {"url": page_url}, session=sid)
    loaded = False
    for _ in range(200):
        res = await call(
            "Runtime.evaluate",
            {"expression": "document.readyState === 'complete'", "returnByValue": True},
            session=sid,
        )
        if res.get("result", {}).get("value"):
            loaded = True
            break

        await asyncio.sleep(0.05)
    if not loaded:
        raise RuntimeError("page did not finish loading")
    sizes = await call(
        "Runtime.evaluate",
        {
            "expression": "JSON.stringify(Array.from(document.images).map(i => [i.naturalWidth, i.naturalHeight]))",
            "returnByValue": True,
        },
        session=sid,
    )
    visit_.image_sizes = [tuple(s) for s in json.loads(sizes["result"]["value"])]
    title = await call(
        "Runtime.evaluate", {"expression": "document.title", "returnByValue": True}, session=sid
    )
    visit_.title = title["result"]["value"]
    layout = await call(
        "Runtime.evaluate", {"expression": _PROBE, "returnByValue": True}, session=sid
    )
    visit_.layout = json.loads(layout["result"]["value"])
    shot = await call("Page.captureScreenshot", {"format": "png"}, session=sid)
    visit_.screenshot = base64.b64decode(shot["data"])
    screenshot.write_bytes(visit_.screenshot)
    for selector, path in scrolled.items():
        js = f"document.querySelector({json.dumps(selector)}).scrollIntoView()"
        await call("Runtime.evaluate", {"expression": js}, session=sid)
        await asyncio.sleep(0.1)
        shot = await call("Page.captureScreenshot", {"format": "png"}, session=sid)
        path.write_bytes(base64.b64decode(shot["data"]))
    for ev in events:
        method, params = ev.get("method"), ev.get("params", {})
        if method == "Network.requestWillBeSent":
            visit_.requests.append(params["request"]["url"])
        elif method == "Runtime.consoleAPICalled" and params.get("type") in ("error", "assert"):
            visit_.console_errors.append(json.dumps(params.get("args", []))[:300])
        elif method == "Runtime.exceptionThrown":
            visit_.console_errors.append(
                params.get("exceptionDetails", {}).get("text", "exception")
            )
        elif method == "Log.entryAdded" and params.get("entry", {}).get("level") == "error":
            visit_.console_errors.append(params["entry"].get("text", "")[:300])
    conn.close()
    return visit_
