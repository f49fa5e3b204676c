"""The `cosim` command line. User mistakes end with one clear message and exit status 2.

A module per command holds its sub-parser and its handler (:mod:`.parser` lists them);
:mod:`.supervisor` runs `cosim run` in a child process it watches, :mod:`.stopping` makes
Ctrl-C and SIGTERM end a command cleanly.
"""

from __future__ import annotations

import signal
import sys
from collections.abc import Sequence

# Nothing heavier at module level, here or in the command modules: `cosim run` first starts
# a supervisor process that only waits for the run's own process (supervise), and plant_fmu
# and pydantic (cosim.schema) would add a quarter of a second to every run there. Each
# command imports what it needs.
from .common import StdoutReaderGone, UserError, print_error
from .parser import build_parser
from .stopping import follow_the_supervisor, on_sigterm
from .supervisor import supervise

__all__ = ["main"]


def main(argv: Sequence[str] | None = None) -> int:
    from ..run_note import supervised

    if argv is None and sys.argv[1:2] == ["run"] and not supervised() \
            and not {"-h", "--help", "--dry-run"} & set(sys.argv[2:]):
        return supervise(sys.argv[1:])
    if argv is None and supervised():
        follow_the_supervisor()
        _dump_fatal_signals()
    from plant_fmu import BuildError

    from ..schema import PipelineError

    if argv is None and not isinstance(sys.stdout, StdoutReaderGone):
        sys.stdout = StdoutReaderGone(sys.stdout)
    args = build_parser().parse_args(argv)
    # Every command ends on SIGTERM as on Ctrl-C (run and sweep keep what they computed).
    previous = signal.signal(signal.SIGTERM, on_sigterm) if argv is None else None
    try:
        return args.func(args) or 0  # a command may return its own status (inspect: 1)
    except (UserError, BuildError, PipelineError) as exc:
        print_error(str(exc))
        return 2
    except KeyboardInterrupt as exc:  # inspect, view: nothing of theirs to keep
        print_error(str(exc) or "interrupted (Ctrl-C)")
        return 2
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


def _dump_fatal_signals() -> None:
    """In the supervised run process: a fatal signal (a plugin's or a plant's binary
    crashing) dumps the Python stack where the supervisor reads whose code it was in."""
    import faulthandler

    from ..run_note import note_path
    from .supervisor import fault_file

    note = note_path()
    if note is not None:
        try:  # kept open for the life of the process: faulthandler writes to its descriptor
            faulthandler.enable(fault_file(note).open("w"))
        except OSError:
            pass
