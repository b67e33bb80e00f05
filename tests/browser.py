"""Open a local page in headless Chromium over the DevTools protocol (with `websockets`):
what it requested, what its console said, its images and a screenshot."""

from __future__ import annotations

import base64
import json
import shutil
import subprocess
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

CHROMIUM = ("chromium", "chromium-browser", "google-chrome")
FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--window-size=1400,1000",
)
IMAGES = (
    "JSON.stringify([...document.images].map(i => ({src: i.getAttribute('src'), complete: i.complete, "
    "width: i.naturalWidth})))"
)


def chromium() -> str | None:
    return next((path for name in CHROMIUM if (path := shutil.which(name))), None)


@dataclass
class PageVisit:
    requests: list[str] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)
    images: list[dict] = field(default_factory=list)
    has_table: bool = False
    screenshot: bytes = b""
    result: object = None  # what `script` returned


def visit(page: Path | str, timeout: float = 60.0, script: str | None = None) -> PageVisit:
    """Load `page` (a file, or a URL) in a fresh headless Chromium and report what happened; `script`,
    an expression (a promise is awaited), is evaluated once the page has loaded, before its
    images are read, and its JSON-able value kept as `result`."""
    from websockets.sync.client import connect

    profile = Path(tempfile.mkdtemp(prefix="chromium-"))
    process = subprocess.Popen(
        [chromium(), *FLAGS, f"--user-data-dir={profile}", "--remote-debugging-port=0", "about:blank"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        port_file = profile / "DevToolsActivePort"
        deadline = time.monotonic() + timeout
        while not (port_file.is_file() and len(port_file.read_text().splitlines()) >= 2):
            if time.monotonic() > deadline or process.poll() is not None:
                raise RuntimeError("Chromium did not start its DevTools endpoint")
            time.sleep(0.1)
        port, path = port_file.read_text().splitlines()[:2]
        visit = PageVisit()
        with connect(f"ws://127.0.0.1:{port}{path}", max_size=None) as socket:
            ids = iter(range(1, 10**6))

            def send(method: str, session: str | None = None, **params: object) -> dict:
                number = next(ids)
                message = {"id": number, "method": method, "params": params}
                if session:
                    message["sessionId"] = session
                socket.send(json.dumps(message))
                while True:
                    reply = json.loads(socket.recv(timeout=timeout))
                    if reply.get("id") == number:
                        if "error" in reply:
                            raise RuntimeError(f"{method}: {reply['error']}")
                        return reply.get("result", {})
                    record(reply)

            def record(event: dict) -> None:
                method, params = event.get("method"), event.get("params", {})
                if method == "Network.requestWillBeSent":
                    visit.requests.append(params["request"]["url"])
                elif method == "Runtime.exceptionThrown":
                    visit.errors.append(params["exceptionDetails"].get("text", "exception"))
                elif method == "Runtime.consoleAPICalled" and params.get("type") == "error":
                    visit.errors.append(str(params.get("args")))
                elif method == "Log.entryAdded" and params["entry"].get("level") == "error":
                    visit.errors.append(params["entry"].get("text", ""))
                elif method == "Page.loadEventFired":
                    loaded.append(True)

            loaded: list[bool] = []
            target = send("Target.createTarget", url="about:blank")["targetId"]
            session = send("Target.attachToTarget", targetId=target, flatten=True)["sessionId"]
            for domain in ("Network", "Runtime", "Log", "Page"):
                send(f"{domain}.enable", session)
            send("Page.navigate", session, url=page if isinstance(page, str) else page.resolve().as_uri())
            while not loaded:
                if time.monotonic() > deadline:
                    raise RuntimeError(f"{page} did not finish loading")
                record(json.loads(socket.recv(timeout=timeout)))
            if script is not None:
                done = send("Runtime.evaluate", session, expression=script, awaitPromise=True, returnByValue=True)
                visit.result = done["result"].get("value")
            evaluated = send("Runtime.evaluate", session, expression=IMAGES, returnByValue=True)
            visit.images = json.loads(evaluated["result"]["value"])
            table = send(
                "Runtime.evaluate", session, expression="!!document.querySelector('table#pvalues')", returnByValue=True
            )
            visit.has_table = bool(table["result"]["value"])
            shot = send("Page.captureScreenshot", session, format="png")
            visit.screenshot = base64.b64decode(shot["data"])
        return visit
    finally:
        process.kill()
        process.wait()
        shutil.rmtree(profile, ignore_errors=True)
