"""Headless Chromium for report tests, without selenium/playwright.

``chromium`` (a pytest fixture, session-scoped) yields a :class:`Chromium` driving the Debian
``chromium`` binary through its command line (``--dump-dom``, ``--screenshot``). When the
binary is missing and the tests run as root with apt available, it is installed with
``apt-get install -y chromium`` (after ``apt-get update`` if the first attempt fails for lack
of package lists); otherwise the tests using it are skipped with the reason.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import pytest

#: Flags this machine needs for a headless, offline, sandbox-less run.
FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--hide-scrollbars", "--mute-audio")
CANDIDATES = ("/usr/bin/chromium", "/usr/bin/chromium-browser")


def _binary() -> str | None:
    for path in CANDIDATES:
        if os.access(path, os.X_OK):
            return path
    return shutil.which("chromium")


def _install() -> str:
    """Install the Debian package; returns why it could not be done (empty on success)."""
    if not hasattr(os, "geteuid") or os.geteuid() != 0:
        return "chromium is not installed and the tests do not run as root to install it"
    if shutil.which("apt-get") is None:
        return "chromium is not installed and apt-get is not available"
    env = dict(os.environ, DEBIAN_FRONTEND="noninteractive")
    cmd = ["apt-get", "install", "-y", "--no-install-recommends", "chromium"]
    first = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=900)
    if first.returncode != 0:
        subprocess.run(["apt-get", "update"], capture_output=True, text=True, env=env,
                       timeout=600)
        second = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=900)
        if second.returncode != 0:
            return f"apt-get install chromium failed: {second.stderr.strip()[-300:]}"
    return ""


class Chromium:
    """One headless Chromium binary; every call uses a fresh temporary profile."""

    def __init__(self, binary: str):
        self.binary = binary

    def _run(self, url: str, extra: list[str], timeout: float = 120.0
             ) -> subprocess.CompletedProcess:
        with tempfile.TemporaryDirectory(prefix="chromium-profile-") as profile:
            cmd = [self.binary, *FLAGS, f"--user-data-dir={profile}", *extra, url]
            return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)

    def dump_dom(self, path: str | os.PathLike, budget_ms: int = 5000) -> str:
        """The DOM after the page's load event (scripts run), as HTML text."""
        res = self._run(Path(path).resolve().as_uri(),
                        [f"--virtual-time-budget={budget_ms}", "--dump-dom"])
        if res.returncode != 0 or not res.stdout.strip():
            raise RuntimeError(f"chromium --dump-dom failed ({res.returncode}): "
                               f"{res.stderr.strip()[-500:]}")
        return res.stdout

    def screenshot(self, path: str | os.PathLike, out: str | os.PathLike,
                   size: tuple[int, int] = (1280, 2000), budget_ms: int = 5000) -> Path:
        """A PNG screenshot of the page at ``size`` (width, height)."""
        out = Path(out).resolve()
        out.parent.mkdir(parents=True, exist_ok=True)
        res = self._run(Path(path).resolve().as_uri(),
                        [f"--virtual-time-budget={budget_ms}", f"--screenshot={out}",
                         f"--window-size={size[0]},{size[1]}"])
        if res.returncode != 0 or not out.exists():
            raise RuntimeError(f"chromium --screenshot failed ({res.returncode}): "
                               f"{res.stderr.strip()[-500:]}")
        return out


@pytest.fixture(scope="session")
def chromium() -> Chromium:
    """A headless Chromium (installed on demand when possible), else skip."""
    binary = _binary()
    if binary is None:
        reason = _install()
        binary = _binary()
        if binary is None:
            pytest.skip(reason or "chromium could not be found after installation")
    return Chromium(binary)
