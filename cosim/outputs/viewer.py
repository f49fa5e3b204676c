"""Opening a recording in the Rerun viewer: on this machine's display, or headless for a
screenshot (tests and reports)."""

from __future__ import annotations

import os
import re
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from plant_fmu.named_file import NotAFile, not_a_file, open_regular, read_text

LAVAPIPE_ICD = Path("/usr/share/vulkan/icd.d/lvp_icd.x86_64.json")  # mesa-vulkan-drivers


class ViewerError(RuntimeError):
    """The viewer could not be found, started or reached."""


def viewer_binary() -> Path:
    """The Rerun viewer executable shipped with rerun-sdk (the ``rerun_cli`` package)."""
    import rerun_cli

    path = Path(rerun_cli.__file__).parent / ("rerun.exe" if sys.platform == "win32" else "rerun")
    if not path.exists():
        raise ViewerError(f"the Rerun viewer is not installed at {path}; "
                          "reinstall rerun-sdk (pip install 'rerun-sdk>=0.41')")
    return path


RRD_MAGIC = b"RRF"  # how every Rerun recording file begins (RRF2 in Rerun 0.41)


def recording_path(run_dir: str | Path) -> Path:
    """``RUN_DIR/recording.rrd`` (or an .rrd path itself), checked to exist."""
    path = Path(run_dir)
    if path.is_dir():
        if not (path / "recording.rrd").is_file():
            raise ViewerError(_sweep_help(path) or _runs_help(path) or
                              f"{path} has no recording.rrd (was it run with --no-recording?)")
        return path / "recording.rrd"
    why = not_a_file(path)
    if why is not None:
        raise ViewerError(f"{path} {why}: give a run folder or an .rrd file")
    try:
        with open_regular(path) as f:
            head = f.read(len(RRD_MAGIC))
    except NotAFile as exc:
        raise ViewerError(f"{exc}: give a run folder or an .rrd file") from None
    if not head.startswith(RRD_MAGIC) and path.suffix != ".rrd":  # (an .rrd: Rerun's verify
        hint = (f" (a pipeline file: run it with cosim run {path}, then view its run folder)"
                if path.suffix == ".toml" else "")                   # says what is wrong)
        raise ViewerError(f"{path} is not a Rerun recording{hint}: give a run folder or an "
                          ".rrd file")
    return path


def _sweep_help(path: Path) -> str | None:
    """For a sweep folder (no recording of its own): where its recorded points are, or how
    to record some; None for any other folder."""
    import json

    try:
        kind = json.loads(read_text(path / "summary.json")).get("kind")
    except (OSError, ValueError, AttributeError):
        return None
    if kind != "sweep":
        return None
    recorded = sorted(p for p in path.iterdir() if p.is_dir()
                      and p.name.startswith(("best_", "worst_"))
                      and (p / "recording.rrd").is_file())
    if not recorded:
        return (f"{path} is a sweep folder: its rows are in results.csv, with no recording; "
                "run the sweep again with --record best,worst to record each run's best and "
                "worst points")
    return (f"{path} is a sweep folder, with no recording of its own; view one of its "
            f"recorded points: {', '.join(f'cosim view {p}' for p in recorded)}")


def _runs_help(path: Path) -> str | None:
    """For a folder of run folders (runs/NAME): which to view; None for any other folder."""
    if (path / "summary.json").exists():
        return None
    runs = sorted(p for p in path.iterdir() if p.is_dir() and not p.is_symlink()
                  and (p / "recording.rrd").is_file())
    if not runs:
        return None
    latest = path / "latest"
    pick = latest if (latest / "recording.rrd").is_file() else runs[-1]
    return (f"{path} holds run folders ({len(runs)} with a recording), not a recording: view "
            f"one, e.g. cosim view {pick}")


def viewer_failure(stderr: str) -> str:
    """The cause in what a viewer that failed printed (a Rust panic's message, e.g. "No
    graphics adapter was found"), not the last lines of its backtrace."""
    lines = [re.sub(r"\x1b\[[0-9;]*m", "", line).strip() for line in stderr.splitlines()]
    lines = [line for line in lines if line and not re.match(
        r"(\d+:|at |stack backtrace|note: |thread '.*' panicked at .*:\d+:\d+:?$)", line)]
    causes = [line for line in lines
              if re.search(r"(?i)error|fail|panic|no graphics adapter|not found|unable", line)]
    return ((causes or lines or ["no output"])[0])[:300]


def verify_recording(path: Path, timeout: float = 120.0) -> None:
    """``rerun rrd verify``: a truncated or foreign file is named at once, rather than after
    the viewer has waited for a recording that never loads."""
    try:
        done = subprocess.run([str(viewer_binary()), "rrd", "verify", str(path)],
                              capture_output=True, text=True, timeout=timeout,
                              env=dict(os.environ, RERUN_ANALYTICS="0"))
    except subprocess.TimeoutExpired:
        raise ViewerError(f"{path}: not verified within {timeout:g} s") from None
    if done.returncode != 0:
        lines = [re.sub(r"\x1b\[[0-9;]*m", "", line).strip()
                 for line in done.stderr.splitlines() if line.strip()]
        reasons = [line.removeprefix("Error: ").split(" -- ")[-1] for line in lines
                   if line.startswith(("Error:", '"')) and "Verification failed" not in line]
        detail = (reasons or lines or ["rrd verify failed"])[0]
        raise ViewerError(f"{path}: not a readable Rerun recording ({detail[:200]}); "
                          "it may be truncated (an interrupted run's writer is given 5 s) or "
                          "not a recording at all")


def has_display() -> bool:
    if sys.platform in ("darwin", "win32"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def no_display_help(path: Path) -> str:
    return (f"no display here (DISPLAY and WAYLAND_DISPLAY are unset). To review {path}:\n"
            f"  - copy it to a machine with a display and run: rerun {path.name}\n"
            f"  - or serve it to a browser from here: {viewer_binary()} --serve-web {path}\n"
            f"    and open the printed http:// address (forward the port if remote)")


def view(run_dir: str | Path) -> int:
    """Open the run folder's recording in the viewer; returns the viewer's exit status."""
    path = recording_path(run_dir)
    if not has_display():
        raise ViewerError(no_display_help(path))
    verify_recording(path)
    return subprocess.call([str(viewer_binary()), str(path)])


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def headless_renderer_available() -> str | None:
    """None if a headless render can be tried here, else the reason it cannot."""
    if sys.platform != "linux":
        return "headless rendering is set up for Linux only"
    if not LAVAPIPE_ICD.exists():
        return (f"{LAVAPIPE_ICD} is missing: install Debian's mesa-vulkan-drivers "
                "(software Vulkan) to render without a GPU")
    return None


@contextmanager
def headless_viewer(recording: str | Path | None = None, size: str = "1600x1000",
                    timeout: float = 60.0) -> Iterator[tuple[object, str]]:
    """The real Rerun viewer, headless (software Vulkan) on 127.0.0.1, optionally showing
    ``recording``. Yields (``rerun.experimental.ViewerClient``, the URL an SDK streams to);
    stops the viewer afterwards."""
    from rerun.experimental import ViewerClient

    reason = headless_renderer_available()
    if reason:
        raise ViewerError(reason)
    port = free_port()
    url = f"rerun+http://127.0.0.1:{port}/proxy"
    # The viewer leaves a rerun-data-<pid> folder in its temporary folder: give it one of
    # ours, removed when it stops.
    scratch = tempfile.TemporaryDirectory(prefix="cosim_viewer_")
    env = dict(os.environ, VK_ICD_FILENAMES=str(LAVAPIPE_ICD), RERUN_ANALYTICS="0",
               TMPDIR=scratch.name)
    command = [str(viewer_binary()), "--headless", "--renderer", "vulkan", "--bind",
               "127.0.0.1", "--port", str(port), "--window-size", size,
               "--hide-welcome-screen", *([str(recording)] if recording else [])]
    process = subprocess.Popen(command, env=env, stdout=subprocess.DEVNULL,
                               stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + timeout
        while True:
            if process.poll() is not None:
                cause = viewer_failure(process.stderr.read().decode(errors="replace"))
                raise ViewerError(f"the viewer exited with status {process.returncode}: "
                                  f"{cause}")
            try:
                client = ViewerClient.connect(url)
                break
            except Exception:  # not listening yet
                if time.monotonic() > deadline:
                    raise ViewerError(f"the viewer did not answer on port {port}") from None
                time.sleep(0.3)
        yield client, url
    finally:
        process.terminate()
        try:
            process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()
        scratch.cleanup()


def wait_for_recording(client, timeout: float = 60.0) -> None:
    """Until the viewer shows a recording (then a moment more, for the views to draw)."""
    deadline = time.monotonic() + timeout
    while not client.get_state().active_recording:
        if time.monotonic() > deadline:
            raise ViewerError("the viewer did not load the recording")
        time.sleep(0.3)
    time.sleep(1.0)


def screenshot(recording: str | Path, png: str | Path, size: str = "1600x1000",
               timeout: float = 60.0) -> Path:
    """Render ``recording`` in the real viewer, headless, and save a screenshot of its
    default blueprint to ``png``."""
    verify_recording(Path(recording))
    with headless_viewer(recording, size, timeout) as (client, _):
        try:
            wait_for_recording(client, timeout)
            client.save_screenshot(str(png))
        except (ConnectionError, OSError, RuntimeError) as exc:
            if isinstance(exc, ViewerError):
                raise
            raise ViewerError(f"the viewer stopped answering while rendering ({exc}); "
                              "nothing was saved") from None
    return Path(png)


def check_reachable(url: str, timeout: float = 3.0) -> str | None:
    """None if something listens at the viewer URL (``rerun+http://HOST:PORT/proxy``),
    else why not, within ``timeout`` seconds."""
    from urllib.parse import urlparse

    parsed = urlparse(url)
    if parsed.scheme not in ("rerun+http", "rerun+https", "rerun") or not parsed.hostname:
        return "not a viewer URL; expected rerun+http://HOST:PORT/proxy"
    try:
        port = parsed.port or 9876
    except ValueError:
        return "its port is not a number"
    try:
        with socket.create_connection((parsed.hostname, port), timeout=timeout):
            return None
    except OSError as exc:
        why = "no answer" if isinstance(exc, TimeoutError) else (exc.strerror or str(exc))
        return (f"cannot reach a Rerun viewer at {parsed.hostname}:{port} ({why} within "
                f"{timeout:g} s); start one with `rerun --port {port}`")
