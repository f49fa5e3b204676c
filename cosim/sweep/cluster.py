"""The Dask cluster a sweep runs on: a LocalCluster on this machine (its workers configured so a
point costs there what it costs in-process, its scratch space ours, the signals that killed
its workers heard), an existing scheduler (connected within a bounded time, its workers'
cosim checked against this one), or SLURM jobs; and closing it quietly."""

from __future__ import annotations

import contextlib
import logging
import os
import re
import shutil
import signal
import sys
import tempfile
import threading
import warnings
import weakref
from collections.abc import Iterator
from typing import TYPE_CHECKING

from .spec import SweepError
from .worker import cosim_version, quiet_heartbeats

if TYPE_CHECKING:
    from dask.distributed import Client, LocalCluster

class _DeathLog(logging.Handler):
    """The signals that ended local worker processes, from their nannies' log (which lives
    in this process with a LocalCluster): Dask's KilledWorker does not say it."""

    def __init__(self) -> None:
        super().__init__(logging.INFO)
        self.signals: list[int] = []

    def emit(self, record: logging.LogRecord) -> None:
        found = re.search(r"killed by signal (\d+)", record.getMessage())
        if found:
            self.signals.append(int(found[1]))
        if record.levelno >= logging.ERROR:  # what the cluster would have shown anyway
            logging.getLogger("distributed").handle(record)

    def last(self) -> str | None:
        """The last signal seen, as "11 (SIGSEGV)"; None if none was."""
        if not self.signals:
            return None
        number = self.signals[-1]
        try:
            return f"{number} ({signal.Signals(number).name})"
        except ValueError:
            return str(number)

    def listen(self) -> None:
        """Hear the nannies' deaths (INFO) while their other messages stay as quiet as the
        cluster made them."""
        nanny = logging.getLogger("distributed.nanny")
        if self not in nanny.handlers:
            nanny.addHandler(self)
        nanny.setLevel(logging.INFO)
        nanny.propagate = False


DEATHS = _DeathLog()


# s, the TCP connection (Client's own timeout), then HANDSHAKE_GRACE s more for the
# handshake: a scheduler answers within a second on a cluster's network, so 10 s in all
# says a silent port is not one without keeping the user waiting.
CONNECT_TIMEOUT = 8.0
HANDSHAKE_GRACE = 2.0


def _connect(scheduler: str) -> Client:
    """A client of the scheduler at ``scheduler``, or :class:`SweepError` within
    CONNECT_TIMEOUT: Client's own timeout covers the TCP connection, not the handshake, so a
    port that accepts and then says nothing (a web server) or something else (a banner, read
    as a message length of exabytes) would hang or exhaust memory. The attempt runs in a
    daemon thread that is abandoned if it does not finish."""

    from dask.distributed import Client

    outcome: dict = {}

    def attempt() -> None:
        try:
            outcome["client"] = Client(scheduler, timeout=f"{CONNECT_TIMEOUT:g}s")
        except BaseException as exc:  # OSError, a garbled handshake, MemoryError
            outcome["error"] = exc

    thread = threading.Thread(target=attempt, daemon=True, name="cosim-connect")
    thread.start()
    thread.join(CONNECT_TIMEOUT + HANDSHAKE_GRACE)
    if "client" in outcome:
        return outcome["client"]
    if "error" in outcome:
        exc = outcome["error"]
        detail = f"{type(exc).__name__}: {exc}"[:200]
        asked = re.search(r"allocate ([\d.]+ \w+)", str(exc))
        if isinstance(exc, MemoryError) and asked:  # a length read from another protocol
            detail = (f"something answered, but not in Dask's protocol: its first bytes, read "
                      f"as a message's length, asked for {asked[1]}")
        raise SweepError(f"--scheduler {scheduler}: no Dask scheduler answered there "
                         f"({detail})")
    raise SweepError(f"--scheduler {scheduler}: something answers there but not as a Dask "
                     f"scheduler (no handshake within {CONNECT_TIMEOUT + HANDSHAKE_GRACE:g} s)")


def check_versions(client: Client, scheduler: str | None) -> None:
    """:class:`SweepError` naming a worker of the cluster whose cosim is not this one's,
    and both versions (a worker joining later is checked by its first task)."""
    if scheduler is None:
        return  # a local cluster runs this very cosim
    mine = cosim_version()
    theirs = client.run(cosim_version)
    for address, version in theirs.items():
        if version != mine:
            raise SweepError(f"--scheduler {scheduler}: the worker {address} runs cosim "
                             f"{version}, this client cosim {mine}: install the same cosim "
                             "on every worker (the same wheel, or a shared path), or stop "
                             "that worker")


@contextlib.contextmanager
def quiet_dask() -> Iterator[None]:
    """Dask's warnings while a cluster starts or closes (a port taken, a slow close) are
    not the user's business and would land in the middle of a progress line."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", module=r"distributed(\.|$)")
        warnings.filterwarnings("ignore", message=r"Port \d+ is already in use")
        yield


def close_cluster(client: Client | None, cluster: LocalCluster | None) -> None:
    """Close the client and the local cluster, if any. A close that fails (a worker caught
    starting as it was ended) is not the sweep's failure: the rows are on disk; Dask's own
    close at exit is spared the same failure, as a traceback after the last line."""
    with quiet_dask():
        if client is not None:
            with contextlib.suppress(Exception):
                client.close()
        if cluster is not None:
            from distributed.deploy.spec import SpecCluster

            try:
                with contextlib.suppress(Exception):  # Dask's asserts on its workers' states
                    cluster.close()
            finally:
                SpecCluster._instances.discard(cluster)


@contextlib.contextmanager
def scratch_space(settings: dict | None = None) -> Iterator[str]:
    """Dask's scratch space (its temporary-directory, with ``settings``) for the cluster made
    inside: a new folder of ours, not /tmp/dask-scratch-space, which Dask leaves behind.
    Removed where the cluster is (:func:`remove_with`), or here if none was made."""
    import dask

    scratch = tempfile.mkdtemp(prefix="cosim-sweep-dask-")
    try:
        with dask.config.set({**(settings or {}), "temporary-directory": scratch}):
            yield scratch
    except BaseException:
        shutil.rmtree(scratch, ignore_errors=True)
        raise


def remove_with(cluster: object, scratch: str) -> None:
    """The scratch folder removed when the cluster is collected (or at exit)."""
    weakref.finalize(cluster, shutil.rmtree, scratch, ignore_errors=True)


def slurm_cluster(workers: int | None = None) -> object:
    """A dask-jobqueue SLURMCluster from the user's Dask configuration (``jobqueue.slurm``
    in ~/.config/dask/jobqueue.yaml or $DASK_CONFIG: queue, account, memory, walltime,
    job_extra_directives...), each job one single-threaded worker (FMUs are not thread-safe),
    scaled to ``workers`` jobs (none yet without). Its workers run this Python on the
    cluster's nodes: this cosim and the pipeline's files at the same paths (a shared
    folder)."""
    try:
        from dask_jobqueue import SLURMCluster
    except ImportError:
        raise SweepError("--cluster slurm needs dask-jobqueue: pip install 'cosim[slurm]' "
                         "(or dask-jobqueue)") from None
    try:
        # its scheduler runs here: its scratch space ours too (the jobs' workers keep theirs
        # on their nodes, as jobqueue.slurm.local-directory says)
        with scratch_space() as scratch:
            cluster = SLURMCluster(cores=1, processes=1, python=sys.executable,
                                   worker_extra_args=["--nthreads", "1"])
            remove_with(cluster, scratch)
    except ValueError as exc:  # jobqueue's own: e.g. no memory configured
        raise SweepError(f"--cluster slurm: {exc} (set it under jobqueue.slurm in "
                         "~/.config/dask/jobqueue.yaml, or in a file $DASK_CONFIG "
                         "names)") from None
    if workers:
        cluster.scale(jobs=workers)
    return cluster


class CancelledBeforeStart(logging.Filter):
    """Drops the one traceback Dask's own code logs when Ctrl-C or SIGTERM lands in the
    first moment of a blocking client call: ``distributed.utils.sync``'s ``cancel()`` reads
    ``future`` before the call has made it, and tornado logs the NameError with its
    traceback ("cannot access free variable 'future'"). Nothing else is wrong: the sweep
    stops as it should. Seen once in a loaded make test (distributed 2026.8.0)."""

    def filter(self, record: logging.LogRecord) -> bool:
        error = record.exc_info[1] if record.exc_info else None
        return not (isinstance(error, NameError) and "'future'" in str(error))


def _quiet_cancellations() -> None:
    """:class:`CancelledBeforeStart` on tornado's log of failed callbacks (once)."""
    log = logging.getLogger("tornado.application")
    if not any(isinstance(f, CancelledBeforeStart) for f in log.filters):
        log.addFilter(CancelledBeforeStart())


def cluster_client(workers: int | None, scheduler: str | None, kind: str = "local"
                   ) -> tuple[Client, LocalCluster | None]:
    """A Dask client: on ``scheduler`` (an existing cluster), on SLURM jobs (``kind``
    "slurm": :func:`slurm_cluster`), or a LocalCluster on 127.0.0.1 with one
    single-threaded process per worker (FMUs are not thread-safe)."""
    _quiet_cancellations()
    from dask.distributed import Client, LocalCluster

    if kind == "slurm":
        cluster = slurm_cluster(workers or 1)
        return Client(cluster), cluster
    if scheduler:
        client = _connect(scheduler)
        try:
            client.wait_for_workers(1, timeout=60)
        except TimeoutError:
            client.close()
            raise SweepError(f"--scheduler {scheduler}: no worker joined within 60 s "
                             "(start one: dask worker ADDRESS --nthreads 1)") from None
        return client, None
    import dask

    # A local worker runs one point at a time, so a worker that dies was killed by its own
    # point (or by the memory of the machine): one more try, not Dask's three more, before
    # the point is failed and its task's other points are run again alone (a crashing plant
    # is reported in half the time). A lower setting of the user's is kept.
    retries = min(dask.config.get("distributed.scheduler.allowed-failures"), LOCAL_RETRIES)
    # Quiet workers: a cancelled point (Ctrl-C) is not a warning the user needs to read.
    with scratch_space({**WORKER_CONFIG,
                        "distributed.scheduler.allowed-failures": retries}) as scratch:
        # The scheduler serves HTTP even without a dashboard, on 8787 unless told: port 0,
        # so a taken 8787 (another cluster) is no warning.
        cluster = LocalCluster(n_workers=workers or os.cpu_count() or 1, threads_per_worker=1,
                               processes=True, host="127.0.0.1", dashboard_address=None,
                               scheduler_kwargs={"dashboard_address": "127.0.0.1:0"},
                               local_directory=scratch, silence_logs=logging.ERROR)
        remove_with(cluster, scratch)
    DEATHS.listen()
    client = Client(cluster)
    client.register_plugin(_quiet_heartbeats_plugin())  # its workers' stderr is ours
    return client, cluster


def _quiet_heartbeats_plugin():
    """A worker plugin that runs :func:`.worker.quiet_heartbeats` on every worker of the
    local cluster, those it starts later too (a class made here: distributed is imported
    only where a cluster is)."""
    from distributed import WorkerPlugin

    class QuietHeartbeats(WorkerPlugin):
        name = "cosim-quiet-heartbeats"

        def setup(self, worker) -> None:
            quiet_heartbeats()

    return QuietHeartbeats()


LOCAL_RETRIES = 1  # a local cluster's tries of a task after its worker died (Dask's: 3)

# What a local worker runs with, against Dask's defaults, so that a point costs on a worker
# what it costs in-process (1.01 times it, against 1.18: the paper's proposed run, 5 s):
WORKER_CONFIG = {
    # Dask's nannies set MALLOC_TRIM_THRESHOLD_=65536 (to hand freed memory back to the OS
    # at once). That also turns off glibc's adaptive mmap threshold, so every trace and
    # evaluation array of every point is a fresh mmap, page-faulted in as it is written:
    # each point took 18 % longer. A worker holds a few traces at a time; glibc's defaults
    # reuse their memory.
    "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None,
    # The statistical profiler samples every thread's stack every 10 ms, taking the GIL
    # from the point's own thread (2-3 % of a point); nobody reads it (no dashboard).
    "distributed.worker.profile.enabled": False,
}
