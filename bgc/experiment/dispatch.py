"""Where a campaign's runs go: local processes (no more than the runs, the cores and the memory
hold; they end when the campaign's process dies), or an existing Dask distributed cluster."""

from __future__ import annotations

import math
import multiprocessing
import os
import signal
import socket
import sys
import threading
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from typing import TYPE_CHECKING, Any, Iterator


from ..arguments import spelled
from .. import arguments
from ..model import DEFAULT_BACKEND
from ..errors import (ArgumentTypeError, ArgumentValueError, ExperimentError, printable)

if TYPE_CHECKING:
    pass

from .campaign_file import RunSpec
from .runs_csv import COLUMNS
from .one_run import model_file, run_one


#: Local worker processes per core, at most: ``run_campaign`` refuses more.
WORKERS_PER_CORE = 4


#: The memory a local worker is assumed to need: fewer workers start when the available memory holds fewer.
#: Measured: a fresh process diagnosing the RO plant (gpf, N = 1000, 300 samples) peaks at 118 MB resident
#: (95 MB of it the imports, shared with the parent after a fork); twice that leaves room for longer runs.
WORKER_MEMORY = 256 * 2**20


#: Seconds to wait for a Dask scheduler (the TCP connection, then its handshake); ``--connect-timeout``.
CONNECT_TIMEOUT = 10.0


# ------------------------------------------------------------------ running
def cores() -> int:
    """The cores this process may run on (its CPU affinity where the system
    tells it, else every core)."""
    try:
        return max(len(os.sched_getaffinity(0)), 1)
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def worker_limit() -> int:
    """The most local worker processes a campaign may ask for:
    :data:`WORKERS_PER_CORE` per core."""
    return WORKERS_PER_CORE * cores()


def check_workers(workers: Any, name: str = "workers") -> int | None:
    """``workers`` when it is None (one per core) or an integer from 1 to
    :func:`worker_limit`; ``name`` is how the caller calls it in messages.

    Raises
    ------
    ArgumentTypeError, ArgumentValueError
        Not an integer (a bool is not one), below 1, or above the limit.
    """
    if workers is None:
        return None
    if not arguments.is_integer(workers):
        raise ArgumentTypeError(f"{name} must be an integer or None, not {type(workers).__name__}", None,
                                "give a number of local processes, e.g. 4")
    limit = worker_limit()
    if workers < 1:
        raise ArgumentValueError(f"{name} is {workers}", None, f"give 1 to {limit} local processes")
    if workers > limit:
        raise ArgumentValueError(
            f"{name} {workers} is more than the limit of {limit} local processes ({WORKERS_PER_CORE} per core, "
            f"{cores()} cores)", None,
            f"give at most {limit}, or run on a Dask cluster with {spelled('scheduler=', '--scheduler')}")
    return int(workers)


def _available_memory() -> int | None:
    """Bytes of memory available to new processes (Linux: MemAvailable), or None when unknown."""
    try:
        with open("/proc/meminfo", encoding="ascii") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (AttributeError, ValueError, OSError):
        return None


def local_workers(requested: int | None, todo: int) -> tuple[int, str | None]:
    """How many local processes to start for ``todo`` runs when
    ``requested`` (None: one per core) were asked for, and why fewer
    (``"runs"``, ``"memory"``, or None): never more than the runs to do, nor
    than the available memory holds at :data:`WORKER_MEMORY` each (at least
    one)."""
    if todo <= 0:
        return 0, None
    n = requested or cores()
    why = None
    if n > todo:
        n, why = todo, "runs"
    memory = _available_memory()
    if memory is not None and n > max(memory // WORKER_MEMORY, 1):
        n, why = max(memory // WORKER_MEMORY, 1), "memory"
    return n, why


def compile_models(specs: list[RunSpec]) -> None:
    """Compile the compiled backend's kernels of every model of ``specs`` once,
    here, into numba's disk cache (bgc's cache folder is named by the model
    text, not its path): the local workers then load them instead of each
    compiling them."""
    from .. import api

    texts = {}
    for spec in specs:
        texts.setdefault(spec.model_text, spec)
    for spec in texts.values():
        api.open(model_file(spec), backend="numba")


def campaign_backend(specs: tuple[RunSpec, ...] | list[RunSpec], backend: str = DEFAULT_BACKEND,
                     scheduler: str | None = None) -> tuple[str, str | None]:
    """The backend a campaign's runs use, and why when ``auto`` chose it
    (None: asked for by name, or left to a Dask cluster's workers).

    A backend asked for by name (or by ``BGC_BACKEND``) is used, or refused
    when it cannot be had. ``auto`` with local workers is
    :func:`bgc.model.package.auto_backend` of the particle-steps of all the
    runs, the kernels cached when every model's are
    (:func:`bgc.api.cache.kernels_cached`): decided once here, so that the
    workers do not each compile numba's kernels. On a Dask cluster
    ``auto`` goes as it is: each worker chooses by what it has installed.

    Raises
    ------
    TrackingError
        An unknown backend, or numba asked for and not installed.
    """
    from ..api import cache
    from ..model import package as packages

    if packages.chosen_by_name(backend):
        return (packages.resolve_backend(backend) if scheduler is None else backend), None
    if scheduler is not None:
        return backend, None
    models: dict[str, tuple[int, bool]] = {}
    work, cached = 0, packages.numba_installed()
    for spec in specs:
        if spec.model_text not in models:
            opened = cache.open_model(model_file(spec))
            models[spec.model_text] = (opened.view.model.settings.steps,
                                       cached and cache.kernels_cached(cache.numba_path(opened)))
        steps, ok = models[spec.model_text]
        work += spec.particles * (spec.steps or steps)
        cached = cached and ok
    return packages.auto_backend(work, cached)


def run_locally(specs: list[RunSpec], workers: int, backend: str = DEFAULT_BACKEND
                ) -> Iterator[tuple[RunSpec, dict]]:
    # fork where there is one: workers inherit the loaded modules and run from a
    # notebook or a script without a __main__ guard (spawn re-imports __main__)
    method = "fork" if "fork" in multiprocessing.get_all_start_methods() else "spawn"
    with ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context(method),
                             initializer=_worker_start, initargs=(os.getpid(),)) as pool:
        futures = {pool.submit(run_one, s, backend): s for s in specs}
        try:
            for f in as_completed(futures):
                spec = futures[f]
                yield spec, _result(f, spec)
        finally:
            for f in futures:
                f.cancel()


#: prctl(2)'s option that has the kernel signal a process when its parent dies (Linux).
_PR_SET_PDEATHSIG = 1


def _worker_start(parent: int) -> None:
    """The initializer of a local worker process: it ends when the campaign's
    process ends, however that ends (a SIGKILL too), instead of waiting for
    work forever. On Linux the kernel sends it SIGTERM when its parent dies
    (``prctl(PR_SET_PDEATHSIG)``); everywhere a daemon thread looks at its
    parent every 0.5 s. Either way it removes its private folders and exits."""
    signal.signal(signal.SIGTERM, _orphaned)
    if sys.platform.startswith("linux"):
        try:
            import ctypes

            ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0)
        except (OSError, AttributeError):  # no libc to call: the thread alone
            pass
    if os.getppid() != parent:  # the parent died before the signal was asked for
        _orphaned()
    threading.Thread(target=_watch_parent, args=(parent,), name="bgc-watch-parent", daemon=True).start()


def _watch_parent(parent: int) -> None:
    while True:
        time.sleep(0.5)
        if os.getppid() != parent:  # re-parented: the campaign's process has died
            _orphaned()


def _orphaned(*_signal: Any) -> None:
    """End this worker now: its folders removed (the finalizers of
    :func:`bgc.api.folders.private_folder`; a worker skips atexit), no clean-up of
    the pool it served (its parent has gone)."""
    try:
        from multiprocessing import util

        from ..api.folders import remove_private_folders

        remove_private_folders()  # also one made while the signal came, before its finalizer was registered
        util._run_finalizers(0)  # noqa: SLF001 - what multiprocessing runs at a worker's normal end
    except Exception:  # noqa: BLE001 - best effort: the exit below is what matters
        pass
    finally:
        os._exit(1)


def scheduler_endpoint(address: str) -> tuple[str, int] | None:
    """(host, port) of a Dask scheduler address reached over TCP
    (``tcp://``, ``tls://`` or a bare ``host:port``), None for another
    transport (``inproc://``, ``ucx://``, ...).

    >>> scheduler_endpoint("tcp://10.0.0.5:8786"), scheduler_endpoint("[::1]:9000"), scheduler_endpoint("ucx://h:1")
    (('10.0.0.5', 8786), ('::1', 9000), None)

    Raises
    ------
    ExperimentError
        The address has no host or no port, or its port is not a number
        from 1 to 65535.
    """
    scheme, sep, rest = address.partition("://")
    if not sep:
        scheme, rest = "tcp", address
    if scheme.lower() not in ("tcp", "tls"):
        return None
    rest = rest.split("/", 1)[0]
    if rest.startswith("["):  # [IPv6]:port
        host, _, tail = rest[1:].partition("]")
        port_text = tail[1:] if tail.startswith(":") else ""
    elif rest.count(":") == 1:
        host, port_text = rest.split(":")
    else:
        host, port_text = rest, ""
    fix = "give tcp://HOST:PORT, e.g. tcp://10.0.0.5:8786 (a scheduler listens on port 8786 unless told otherwise)"
    if not host:
        raise ExperimentError(f"scheduler address {printable(address)} names no host", None, fix)
    if not port_text:
        raise ExperimentError(f"scheduler address {printable(address)} names no port", None, fix)
    if not port_text.isdigit() or not 1 <= int(port_text) <= 65535:
        raise ExperimentError(f"scheduler address {printable(address)}: port '{printable(port_text)}' is not a "
                              "number from 1 to 65535", None, fix)
    return host, int(port_text)


def check_scheduler(address: str, timeout: float = CONNECT_TIMEOUT) -> None:
    """Fail fast when no Dask scheduler answers at ``address``: one TCP
    connection to its host and port (a refused connection fails at once;
    Dask's client would retry it for its whole timeout), then Dask's
    handshake (a server that takes the connection but never answers holds
    Dask's client forever, one that answers something else can crash it),
    each within ``timeout`` seconds. Addresses of other transports than
    TCP and TLS are left to Dask.

    Raises
    ------
    ExperimentError
        The address is malformed, the host is unknown, refuses the
        connection, does not answer in time or is no Dask scheduler.
    """
    endpoint = scheduler_endpoint(address)
    if endpoint is None:
        return
    _tcp_probe(address, endpoint, timeout)
    _handshake_probe(address, timeout)


def _tcp_probe(address: str, endpoint: tuple[str, int], timeout: float) -> None:
    host, port = endpoint
    where = f"the Dask scheduler at {printable(address)}"
    start = "start one (dask scheduler; dask worker ADDRESS) or check the address and port"
    try:
        with socket.create_connection((host, port), timeout=timeout):
            return
    except ConnectionRefusedError:
        raise ExperimentError(f"cannot reach {where}: connection refused (nothing listens at port {port})", None,
                              start) from None
    except socket.gaierror as exc:
        raise ExperimentError(f"cannot reach {where}: unknown host '{printable(host)}' ({printable(str(exc))})",
                              None, "check the host name") from None
    except (TimeoutError, socket.timeout):
        raise ExperimentError(f"cannot reach {where}: no answer within {timeout:g} s", None,
                              "check the address, the network and firewalls, or wait longer with "
                              "--connect-timeout SECONDS") from None
    except OSError as exc:
        raise ExperimentError(f"cannot reach {where}: {printable(exc.strerror or str(exc))}", None, start) from None


def _handshake_probe(address: str, timeout: float) -> None:
    """Dask's handshake with the scheduler, given up after ``timeout``
    seconds (in a thread of its own: the caller may be inside an event loop,
    as in a notebook)."""
    import asyncio

    from distributed.comm import connect
    from distributed.security import Security

    failure: list[BaseException] = []

    async def probe() -> None:
        comm = await asyncio.wait_for(connect(address, timeout=timeout, **Security().get_connection_args("client")),
                                      timeout)
        await comm.close()

    def run() -> None:
        try:
            asyncio.run(probe())
        except BaseException as exc:  # noqa: BLE001 - any failure means no scheduler: said below
            failure.append(exc)

    thread = threading.Thread(target=run, name="bgc-scheduler-probe", daemon=True)
    thread.start()
    thread.join(timeout + 5.0)
    where = f"the Dask scheduler at {printable(address)}"
    if thread.is_alive() or (failure and isinstance(failure[0], (TimeoutError, asyncio.TimeoutError))):
        raise ExperimentError(f"cannot reach {where}: the server takes the connection but does not answer within "
                              f"{timeout:g} s", None, "check that it is the address dask scheduler prints, or wait "
                              "longer with --connect-timeout SECONDS")
    if failure:
        exc = failure[0]
        said = "not Dask's protocol" if isinstance(exc, MemoryError) else f"{type(exc).__name__}: {exc}"
        raise ExperimentError(f"cannot reach {where}: {printable(said)[:300]}", None,
                              "check that it is the address dask scheduler prints")


def run_on_dask(specs: list[RunSpec], address: str, timeout: float, backend: str = DEFAULT_BACKEND
          ) -> Iterator[tuple[RunSpec, dict]]:
    try:
        from distributed import Client
        from distributed import as_completed as dask_completed
    except ImportError:  # pragma: no cover - a dependency of bgc
        raise ExperimentError(f"{spelled('scheduler=', '--scheduler')} needs dask.distributed", None,
                              "pip install 'dask[distributed]'") from None
    check_scheduler(address, timeout)
    try:
        client = Client(address, timeout=timeout)
    except Exception as exc:  # noqa: BLE001 - whatever Dask raises, the scheduler is out of reach
        raise ExperimentError(f"cannot reach the Dask scheduler at {printable(address)}: {printable(str(exc))}",
                              None, "start one (dask scheduler; dask worker ADDRESS), check the address, or wait "
                              "longer with --connect-timeout SECONDS") from None
    try:
        futures = client.map(run_one, specs, backend=backend, key=[f"bgc-run-{s.id}-{s.index}" for s in specs],
                             pure=False)
        by_key = {f.key: s for f, s in zip(futures, specs)}
        try:
            for f in dask_completed(futures):
                spec = by_key[f.key]
                yield spec, _result(f, spec)
        finally:
            client.cancel(futures)
    finally:
        client.close()


def _result(future, spec: RunSpec) -> dict[str, Any]:
    """A future's row; a worker that died or a task the engine lost is a failed run."""
    try:
        return future.result()
    except Exception as exc:  # noqa: BLE001
        row = dict.fromkeys(COLUMNS)
        row.update(spec.identity())
        row.update(status="failed", failure=printable(f"{type(exc).__name__}: {exc}")[:500])
        return row


def check_timeout(value: Any, name: str = "connect_timeout") -> float:
    """``value`` as seconds when it is a finite number above 0.

    Raises
    ------
    ArgumentTypeError, ArgumentValueError
        Not a number (a bool is not one), or not finite and above 0.
    """
    if not arguments.is_real(value):
        raise ArgumentTypeError(f"{name} must be a number of seconds, not {type(value).__name__}", None,
                                f"give {name}={CONNECT_TIMEOUT:g}")
    seconds = arguments.as_float(value)
    if not (math.isfinite(seconds) and seconds > 0):
        raise ArgumentValueError(f"{name} is {printable(str(value))[:40]}", None,
                                 "give a finite number of seconds above 0")
    return seconds
