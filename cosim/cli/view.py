"""`cosim view`: open a run folder's recording in the Rerun viewer, or render it as a PNG."""

from __future__ import annotations

import argparse
import os
import re
from pathlib import Path

from .common import UserError


def add_parser(commands: argparse._SubParsersAction) -> None:
    p = commands.add_parser(
        "view", help="open a run folder's recording in the Rerun viewer",
        description="Open RUN_DIR/recording.rrd in the Rerun viewer, with the layout stored in "
        "it (the paper's Figs. 2-4 per run, barriers, observer error, the arm). Without a "
        "display, says how to view it elsewhere.")
    p.add_argument("run_dir", metavar="RUN_DIR", help="a run folder, or an .rrd file")
    p.add_argument("--screenshot", metavar="PNG", type=Path, default=None,
                   help="instead of opening a window, render the layout headless (software "
                   "Vulkan: Debian's mesa-vulkan-drivers) and save it as PNG")
    p.add_argument("--size", metavar="WxH", default=None,
                   help="the screenshot's size in pixels (default 1600x1000); with more "
                   "than two runs each run has a tab of its own")
    p.set_defaults(func=handle)


def handle(args: argparse.Namespace) -> None:
    from ..outputs.viewer import ViewerError, recording_path, screenshot, view

    try:
        if args.size is not None and not args.screenshot:
            raise UserError(f"--size {args.size}: sizes the --screenshot PNG; a window opened "
                            "by `cosim view` is resized by hand")
        if args.screenshot:
            size = _window_size(args.size or "1600x1000")
            if args.screenshot.is_dir():
                raise UserError(f"--screenshot {args.screenshot}: is a folder; give the PNG "
                                f"file to write, e.g. {args.screenshot / 'recording.png'}")
            if args.screenshot.suffix.lower() != ".png":
                raise UserError(f"--screenshot {args.screenshot}: the screenshot is a PNG; "
                                f"give a name ending in .png, e.g. "
                                f"{args.screenshot.with_suffix('.png')}")
            folder = args.screenshot.resolve().parent
            if not folder.is_dir() or not os.access(folder, os.W_OK):
                raise UserError(f"--screenshot {args.screenshot}: cannot write there "
                                f"({folder} is not a writable folder)")
            print(screenshot(recording_path(args.run_dir), args.screenshot, size))
            return
        status = view(args.run_dir)
    except ViewerError as exc:
        raise UserError(str(exc)) from None
    if status:
        raise UserError(f"the Rerun viewer exited with status {status}")


def _window_size(size: str) -> str:
    """``WIDTHxHEIGHT`` in pixels, each 200 to 8000, or one message saying so."""
    match = re.fullmatch(r"(\d+)x(\d+)", size.strip())
    if not match or not all(200 <= int(v) <= 8000 for v in match.groups()):
        raise UserError(f"--size {size!r}: expected WIDTHxHEIGHT in pixels, each from 200 to "
                        "8000, e.g. 1600x1000")
    return f"{int(match[1])}x{int(match[2])}"
