"""Where ``mi-loop fit-batch`` runs: a local Dask cluster, or a running one named by its scheduler.

A local cluster has :data:`LOCAL_WORKERS` worker processes (or ``--workers``)
of one thread each: every fit already runs on all of Dr.Jit's threads. A
running cluster is named by its scheduler's address (``tcp://host:port``) or
by the JSON file that ``dask scheduler --scheduler-file F`` writes; its
workers need mi_loop installed and the inputs and OUTDIR at the same paths
(a shared file system).
"""
from __future__ import annotations

import contextlib
import logging

from mi_loop.errors import fail
from mi_loop.io.documents import read_json

__all__ = ["CONNECT_TIMEOUT", "LOCAL_WORKERS", "connect", "dashboard_link", "scheduler_address"]

#: Worker processes of the local cluster when ``--workers`` is not given.
LOCAL_WORKERS = 2
#: Seconds to wait for a running scheduler before giving up.
CONNECT_TIMEOUT = 10.0

_SCHEDULER = "a scheduler address tcp://host:port or the JSON file that `dask scheduler --scheduler-file` writes"


def scheduler_address(scheduler: str) -> str:
    """Return the address of ``--scheduler``: the address itself, or the ``address`` in a scheduler file.

    Parameters
    ----------
    scheduler : str
        ``protocol://host:port``, or the path of a scheduler JSON file.

    Returns
    -------
    str
        ``protocol://host:port``.

    Raises
    ------
    ValueError
        If ``scheduler`` is no address and no readable JSON file with an ``address``.

    Examples
    --------
    >>> scheduler_address("tcp://10.0.0.5:8786")
    'tcp://10.0.0.5:8786'
    """
    if "://" in scheduler:
        return scheduler
    info = read_json(scheduler, "fit-batch --scheduler", _SCHEDULER)
    address = info.get("address") if isinstance(info, dict) else None
    if not isinstance(address, str) or "://" not in address:
        fail("fit-batch --scheduler", _SCHEDULER, f"'{scheduler}' without an 'address' protocol://host:port")
    return address


def dashboard_link(client) -> str:
    """Return the address of the cluster's dashboard, or ``''`` when it has none (no bokeh on the scheduler).

    Parameters
    ----------
    client : distributed.Client

    Returns
    -------
    str
    """
    def bokeh_installed():            # a local function: sent by value, the scheduler needs no mi_loop
        import importlib.util

        return importlib.util.find_spec("bokeh") is not None

    try:    # without bokeh the scheduler still serves a page that asks for it: not a dashboard
        if not client.run_on_scheduler(bokeh_installed):
            return ""
        return client.dashboard_link or ""
    except (KeyError, AttributeError, ImportError, OSError):
        return ""


@contextlib.contextmanager
def connect(scheduler: str | None, workers: int | None, log):
    """Yield a Dask client: of a new local cluster, or of the running cluster ``scheduler``.

    Parameters
    ----------
    scheduler : str or None
        ``--scheduler`` (see :func:`scheduler_address`); None starts a local cluster.
    workers : int or None
        Worker processes of the local cluster (default :data:`LOCAL_WORKERS`).
    log : mi_loop.app.progress.Reporter
        Says where the batch runs and, once, the dashboard's address.

    Yields
    ------
    distributed.Client
        Closed, with the local cluster, when the block ends.

    Raises
    ------
    ValueError
        If ``scheduler`` names no address or no scheduler answers there within :data:`CONNECT_TIMEOUT`.
    """
    from distributed import Client, LocalCluster

    with contextlib.ExitStack() as stack:
        if scheduler is None:
            workers = LOCAL_WORKERS if workers is None else workers
            log.say(f"starting a local Dask cluster: {workers} worker processes, one thread each")
            cluster = stack.enter_context(LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                                       dashboard_address=":0", silence_logs=logging.ERROR))
            client = stack.enter_context(Client(cluster))
        else:
            address = scheduler_address(scheduler)
            try:
                client = stack.enter_context(Client(address, timeout=CONNECT_TIMEOUT))
            except OSError as exc:            # TimeoutError: nothing answered
                fail("fit-batch --scheduler", "a running Dask scheduler", f"'{address}': {exc}")
            n = len(client.nthreads())
            log.say(f"connected to the Dask scheduler {address}: {n} workers")
            if n == 0:
                log.warning(f"the Dask scheduler {address} has no workers yet: the inputs wait for them")
        link = dashboard_link(client)
        if link:
            log.say(f"Dask dashboard: {link}")
        yield client
