"""Open a local HTML file in headless Chromium and report what a user would see: whether it loaded, its DOM, the
state of its images and videos, and every console error, uncaught exception and error log entry.

Drives the DevTools protocol over --remote-debugging-pipe (Chromium reads commands on fd 3 and writes replies on
fd 4, each message JSON ending in a NUL byte), so nothing listens on the network and only the standard library is
needed. Chromium's own --enable-logging output does not tell console levels apart, hence the protocol.
"""

from __future__ import annotations

import contextlib
import json
import os
import select
import shlex
import shutil
import subprocess
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--mute-audio",
    "--remote-debugging-pipe",
]

# Waits for every video to have decoded a frame (or failed), then describes the page's media.
MEDIA_STATE = """
(async () => {
  const videos = [...document.querySelectorAll('video')];
  await Promise.all(videos.map(v => v.readyState >= 2 || v.error ? 0 : new Promise(done => {
    v.addEventListener('loadeddata', done); v.addEventListener('error', done); setTimeout(done, 10000);
  })));
  return JSON.stringify({
    title: document.title,
    images: [...document.images].map(i => ({complete: i.complete, width: i.naturalWidth, height: i.naturalHeight})),
    videos: videos.map(v => ({ready: v.readyState, error: v.error ? v.error.code : null,
                              width: v.videoWidth, height: v.videoHeight, duration: v.duration})),
  });
})()
"""


@dataclass
class PageReport:
    loaded: bool
    dom: str
    media: dict
    console_errors: list[str] = field(default_factory=list)


class _Pipe:
    def __init__(self, write_fd: int, read_fd: int, timeout: float) -> None:
        self.write_fd, self.read_fd, self.deadline = write_fd, read_fd, time.monotonic() + timeout
        self.buffer = b""
        self.next_id = 0
        self.events: list[dict] = []

    def _read_message(self) -> dict:
        while b"\0" not in self.buffer:
            left = self.deadline - time.monotonic()
            if left <= 0 or not select.select([self.read_fd], [], [], left)[0]:
                raise TimeoutError("chromium did not answer in time")
            chunk = os.read(self.read_fd, 1 << 20)
            if not chunk:
                raise RuntimeError("chromium closed the DevTools pipe")
            self.buffer += chunk
        message, _, self.buffer = self.buffer.partition(b"\0")
        return json.loads(message)

    def send(self, method: str, params: dict | None = None, session: str | None = None) -> dict:
        self.next_id += 1
        message = {"id": self.next_id, "method": method, "params": params or {}}
        if session:
            message["sessionId"] = session
        os.write(self.write_fd, json.dumps(message).encode() + b"\0")
        while True:
            reply = self._read_message()
            if reply.get("id") == self.next_id:
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error']}")
                return reply.get("result", {})
            self.events.append(reply)

    def wait_for(self, method: str) -> dict:
        for i, event in enumerate(self.events):
            if event.get("method") == method:
                return self.events.pop(i)
        while True:
            event = self._read_message()
            if event.get("method") == method:
                return event
            self.events.append(event)


def _errors(events: list[dict]) -> list[str]:
    found = []
    for event in events:
        method, params = event.get("method"), event.get("params", {})
        if method == "Runtime.consoleAPICalled" and params.get("type") in ("error", "assert"):
            found.append(
                "console."
                + params["type"]
                + ": "
                + " ".join(str(a.get("value", a.get("description", ""))) for a in params.get("args", []))
            )
        elif method == "Runtime.exceptionThrown":
            details = params.get("exceptionDetails", {})
            found.append("exception: " + details.get("exception", {}).get("description", details.get("text", "")))
        elif method == "Log.entryAdded" and params.get("entry", {}).get("level") == "error":
            found.append("log: " + params["entry"].get("text", ""))
    return found


def inspect_page(path: str | Path, timeout: float = 90.0) -> PageReport:
    url = Path(path).resolve().as_uri()
    to_chrome_read, to_chrome_write = os.pipe()
    from_chrome_read, from_chrome_write = os.pipe()
    profile = tempfile.mkdtemp(prefix="canter-chromium-")
    command = " ".join(shlex.quote(part) for part in [CHROMIUM, *FLAGS, f"--user-data-dir={profile}"])
    # bash, not sh: dash redirects only single-digit descriptors.
    process = subprocess.Popen(
        ["/bin/bash", "-c", f"exec {command} 3<&{to_chrome_read} 4>&{from_chrome_write}"],
        pass_fds=(to_chrome_read, from_chrome_write),
        stdin=subprocess.DEVNULL,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    os.close(to_chrome_read)
    os.close(from_chrome_write)
    pipe = _Pipe(to_chrome_write, from_chrome_read, timeout)
    try:
        target = pipe.send("Target.createTarget", {"url": "about:blank"})["targetId"]
        session = pipe.send("Target.attachToTarget", {"targetId": target, "flatten": True})["sessionId"]
        for domain in ("Runtime", "Log", "Page"):
            pipe.send(f"{domain}.enable", session=session)
        navigation = pipe.send("Page.navigate", {"url": url}, session=session)
        loaded = "errorText" not in navigation
        if loaded:
            pipe.wait_for("Page.loadEventFired")
        media = json.loads(
            pipe.send(
                "Runtime.evaluate",
                {"expression": MEDIA_STATE, "awaitPromise": True, "returnByValue": True},
                session=session,
            )["result"]["value"]
        )
        dom = pipe.send(
            "Runtime.evaluate",
            {"expression": "document.documentElement.outerHTML", "returnByValue": True},
            session=session,
        )["result"]["value"]
        with contextlib.suppress(RuntimeError):  # the pipe may close before the reply arrives
            pipe.send("Browser.close")
        return PageReport(loaded, dom, media, _errors(pipe.events))
    finally:
        os.close(to_chrome_write)
        os.close(from_chrome_read)
        try:
            process.wait(timeout=15)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()
        shutil.rmtree(profile, ignore_errors=True)
