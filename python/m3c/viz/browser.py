"""Screenshots of a web page in headless Chromium (the viewer's test and its README picture).

Chromium's --screenshot flag shoots as soon as the page has loaded, before viser's websocket has sent the scene,
so this drives Chromium through its DevTools protocol instead: open the page, wait, capture. WebGL runs on
SwiftShader (software), so no GPU is needed.
"""

from __future__ import annotations

import base64
import json
import os
import shutil
import signal
import socket
import subprocess
import tempfile
import time
import urllib.request
from pathlib import Path


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def find_chromium() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        path = shutil.which(name)
        if path:
            return path
    return None


def screenshot_page(url: str, png: str | Path, width: int = 1400, height: int = 800, wait_s: float = 8.0,
                    chromium: str | None = None, script: str | None = None, done=None,
                    timeout_s: float = 60.0) -> Path:
    """Loads `url` in headless Chromium, waits `wait_s` seconds, runs the JavaScript `script` if given, and
    writes the window as PNG to `png`. With `done` (PNG bytes -> bool), shoots again every 2 s until it holds
    or `timeout_s` has passed since the page was opened (a busy machine draws a WebGL scene slowly)."""
    from websockets.sync.client import connect

    chromium = chromium or find_chromium()
    if chromium is None:
        raise FileNotFoundError("no Chromium found; install it (Debian: apt-get install chromium)")
    port = free_port()
    # Chromium's helper processes (crash handler, GPU) may still write into the profile while they exit: a leftover
    # file must not fail the screenshot.
    with tempfile.TemporaryDirectory(prefix="m3c-chromium-", ignore_cleanup_errors=True) as profile:
        proc = subprocess.Popen([chromium, "--headless", "--no-sandbox", "--use-angle=swiftshader",
                                 "--enable-unsafe-swiftshader", f"--window-size={width},{height}",
                                 f"--remote-debugging-port={port}", f"--user-data-dir={profile}", "about:blank"],
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
        try:
            target = None
            deadline = time.monotonic() + 30.0
            while target is None:
                try:
                    with urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=2) as response:
                        pages = [p for p in json.load(response) if p.get("type") == "page"]
                    target = pages[0]["webSocketDebuggerUrl"] if pages else None
                except OSError:
                    pass
                if target is None:
                    if time.monotonic() > deadline or proc.poll() is not None:
                        raise RuntimeError(f"Chromium ({chromium}) did not open its DevTools port")
                    time.sleep(0.2)
            with connect(target, max_size=None, open_timeout=10) as ws:
                def call(message_id: int, method: str, **params):
                    ws.send(json.dumps({"id": message_id, "method": method, "params": params}))
                    while True:
                        reply = json.loads(ws.recv(timeout=60))
                        if reply.get("id") == message_id:
                            if "error" in reply:
                                raise RuntimeError(f"Chromium {method}: {reply['error']}")
                            return reply.get("result", {})

                call(1, "Page.enable")
                call(2, "Page.navigate", url=url)
                opened = time.monotonic()
                time.sleep(wait_s)
                message_id = 3
                while True:
                    if script:
                        call(message_id, "Runtime.evaluate", expression=script)
                    data = base64.b64decode(call(message_id + 1, "Page.captureScreenshot", format="png")["data"])
                    message_id += 2
                    if done is None or done(data) or time.monotonic() - opened > timeout_s:
                        break
                    time.sleep(2.0)
        finally:
            # Our own headless instance with a throw-away profile, in its own process group: nothing to save, and
            # its helper processes go with it.
            try:
                os.killpg(proc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            proc.wait()
    png = Path(png)
    png.write_bytes(data)
    return png
