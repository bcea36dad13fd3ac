"""Headless Chromium (the distribution's package) driven over the DevTools pipe.

``--remote-debugging-pipe`` makes Chromium read DevTools commands from file
descriptor 3 and write replies to 4, as NUL-terminated JSON: no port, no
websocket library and no browser download.  Enough of the protocol to open a
page and evaluate JavaScript in it.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import select
import shutil
import subprocess
import tempfile
import time

#: Flags that keep Chromium offline, quiet and runnable as root in a container.
FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--mute-audio", "--remote-debugging-pipe")


def executable():
    """The Chromium binary, or ``None``."""
    return shutil.which("chromium") or shutil.which("chromium-browser")


class Browser:
    """A headless Chromium with one page; use as a context manager.

    Parameters
    ----------
    timeout : float
        Seconds any one command may take.
    """

    def __init__(self, timeout=30.0):
        self.timeout = timeout
        self._profile = tempfile.mkdtemp(prefix="fastdet-chromium-")
        ours_read, theirs_write = os.pipe()
        theirs_read, ours_write = os.pipe()
        # Above any descriptor the child's dup2 onto 3 and 4 could overwrite.
        high_read = fcntl.fcntl(theirs_read, fcntl.F_DUPFD, 10)
        high_write = fcntl.fcntl(theirs_write, fcntl.F_DUPFD, 10)

        def wire():
            os.dup2(high_read, 3)
            os.dup2(high_write, 4)

        self._process = subprocess.Popen(
            [executable(), *FLAGS, f"--user-data-dir={self._profile}", "about:blank"],
            pass_fds=(3, 4), preexec_fn=wire, stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        for fd in (theirs_read, theirs_write, high_read, high_write):
            os.close(fd)
        self._read, self._write = ours_read, ours_write
        self._buffer = b""
        self._next_id = 0
        self.session = None

    def __enter__(self):
        target = self.call("Target.createTarget", url="about:blank")["targetId"]
        self.session = self.call("Target.attachToTarget", targetId=target,
                                 flatten=True)["sessionId"]
        return self

    def __exit__(self, *exc):
        with contextlib.suppress(Exception):
            self.call("Browser.close", _session=False)
        try:
            self._process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self._process.kill()
            self._process.wait()
        os.close(self._read)
        os.close(self._write)
        shutil.rmtree(self._profile, ignore_errors=True)

    def call(self, method, _session=True, **params):
        """Send one DevTools command and return its result (raises on a protocol error)."""
        self._next_id += 1
        message = {"id": self._next_id, "method": method, "params": params}
        if _session and self.session:
            message["sessionId"] = self.session
        os.write(self._write, json.dumps(message).encode() + b"\0")
        deadline = time.monotonic() + self.timeout
        while True:
            while b"\0" in self._buffer:
                raw, self._buffer = self._buffer.split(b"\0", 1)
                reply = json.loads(raw)
                if reply.get("id") == self._next_id:
                    if "error" in reply:
                        raise RuntimeError(f"{method}: {reply['error']}")
                    return reply["result"]
            ready, _, _ = select.select([self._read], [], [], max(0.0, deadline - time.monotonic()))
            if not ready:
                raise TimeoutError(f"Chromium did not answer {method} in {self.timeout} s")
            chunk = os.read(self._read, 1 << 16)
            if not chunk:
                raise EOFError("Chromium closed the DevTools pipe")
            self._buffer += chunk

    def open(self, url):
        """Load ``url`` and wait for its ``load`` event (polled)."""
        self.call("Page.navigate", url=url)
        self.wait_for("document.readyState === 'complete'")

    def evaluate(self, expression):
        """The JSON value of a JavaScript expression (promises awaited)."""
        result = self.call("Runtime.evaluate", expression=expression, awaitPromise=True,
                           returnByValue=True)
        if "exceptionDetails" in result:
            raise RuntimeError(f"{expression}: {result['exceptionDetails']}")
        return result["result"].get("value")

    def wait_for(self, condition, seconds=15.0):
        """Poll a JavaScript condition until it holds; returns False after ``seconds``."""
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            if self.evaluate(f"Boolean({condition})"):
                return True
            time.sleep(0.1)
        return False
