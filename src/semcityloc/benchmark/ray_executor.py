"""The run loop's queries on Ray: a local Ray runtime or an existing cluster (``--executor ray``).

Why Ray: a survey flight is hundreds to thousands of photos; Ray runs the same workers on a laptop's
cores or on a cluster's machines with one call, keeps what every worker needs in its object store, and
tells the driver when a worker process died. ``run_ray`` is a drop-in for the run loop's process pool
(``benchmark.run``): the driver alone appends the rows it yields (one fsync'd line per query, so a killed
driver resumes as today).

- Start-up: ``ray.init(address="local", num_cpus=workers)`` starts a runtime of its own (no dashboard, no
  log forwarding, a small object store; even when a ``ray start`` cluster runs on this machine, which
  plain ``ray.init`` would join) and shuts it down at the end; ``address`` joins an existing cluster
  instead (its CPUs decide how many workers run at once: ``workers`` actors are started). A runtime already
  up in this process (a test, a notebook) is used and left up. An address is ``host:port``,
  ``ray://host:port`` (Ray's client: ``pip install 'ray[client]'``, which the ``[ray]`` extra does not
  install; checked first) or ``auto``; any other form is refused in one line (``check_address``), where
  Ray raised ``Invalid address format`` from deep inside. An address where nothing answers is refused in
  one line (``BenchmarkError``) within ``CONNECT_TIMEOUT_S``: Ray itself retries for minutes, then raises
  from deep inside; ``auto`` likewise, the address Ray finds for it probed first (``auto_address``: a
  ``ray_current_cluster`` file a ``ray start`` long gone left in Ray's temporary folder made Ray wait
  minutes for it), and with no cluster found Ray's own line. A failed
  join names ``RAY_AUTH_MODE=token`` when this machine holds a Ray token: a head started where
  ``~/.ray/auth_token`` exists asks for it, and Ray's clients send it only in token mode. A runtime of
  its own gets a token for the run in its environment (``RAY_AUTH_TOKEN``, ``run_token``) unless the
  user set one: Ray then writes none to ``~/.ray/auth_token`` (a local runtime otherwise leaves one in
  the user's home, which later heads on the machine ask for).
- Shipping: the worker arguments (the typed spec, the source with its city model or tile store) are put
  in the object store once (``ray.put``); each of ``workers`` actors builds its ``_Worker`` (method,
  render scene) from them once and then localizes one query at a time.
- Failures: a query whose worker process dies (killed, out of memory) is given to a new worker once more;
  if that worker dies too, the query gets a row with status ``failed`` and the reason (and is not tried
  again on resume). An exception raised by the query itself is raised here, as with the process pool.
- The driver's death: no guard of ours, unlike the process pool's workers (``run._die_with_parent``). Ray's
  workers are not this process's children but the raylet's, so ``PR_SET_PDEATHSIG`` in them would bind
  them to the raylet, which Ray does already; Ray ends them with the driver itself. A driver killed
  (SIGKILL) takes its local runtime's head with it (Ray starts the GCS and the raylet with
  ``PR_SET_PDEATHSIG``), and the workers end with their raylet within seconds (Ray's dashboard and
  runtime-environment agents a minute later, by themselves: the raylet starts them for every runtime, no
  ``ray.init`` option leaves them out, and ``ray stop`` ends them at once, docs/scale.md); on a cluster,
  actors die with their owner,
  the driver (measured by hand: within a second). SIGTERM: ``ray.init`` installs a handler that exits the
  driver, so ``run_ray``'s ``finally`` (and Ray's ``atexit``) calls ``ray.shutdown``, which ends every
  process the runtime started (``tests/test_ray_executor.py``,
  ``test_ray_workers_end_with_the_run_that_started_them``).

Numbers do not depend on the executor or the worker count (``benchmark.run``: queries and the localizer
are seeded per query).
"""

from __future__ import annotations

import contextlib
import importlib.util
import os
import secrets
import socket
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numba

from semcityloc.benchmark.results import failed_row
from semcityloc.errors import BenchmarkError, OptionalDependencyError, parameter

RETRIES = 1  # a query whose worker died is tried this many more times
# Object store of a local runtime (bytes): the shipped models are tens of MB; Ray's default takes 30% of RAM.
OBJECT_STORE_BYTES = 512 * 1024 * 1024
CONNECT_TIMEOUT_S = 5.0  # how long a cluster's address may take to answer before it is refused
_AUTO_FOUND = (  # where Ray's `auto` finds a cluster's address (``auto_address``)
    ", the address Ray found for auto (RAY_ADDRESS, or ray_current_cluster in Ray's temporary folder, "
    "/tmp/ray, left by a `ray start` whose cluster is gone: `ray stop` clears it)"
)
_START_HINT = (
    f"start one with `ray start --head`, or leave out {parameter('ray_address')} for a local runtime"
)


def import_ray():
    """The ``ray`` module, or the one-line install hint."""
    try:
        import ray  # optional extra [ray]: imported only when the Ray executor runs
    except ImportError as exc:
        raise OptionalDependencyError("ray", "ray", parameter("executor", "ray")) from exc
    return ray


class _RayWorker:
    """One Ray actor: a run-loop worker built once from the shipped arguments."""

    def __init__(self, make_worker: Callable[..., Any], threads: int, worker_args: tuple):
        numba.set_num_threads(max(1, min(threads, numba.config.NUMBA_NUM_THREADS)))
        self.worker = make_worker(*worker_args)

    def pid(self) -> int:
        """The actor's process id: which worker process runs its queries (checks, debugging)."""
        return os.getpid()

    def run(self, index: int) -> dict[str, str]:
        """Run query ``index`` in this actor's worker; its result row as the local executor's."""
        return self.worker.run(index)


def run_ray(
    todo: list[int],
    workers: int,
    make_worker: Callable[..., Any],
    worker_args: tuple,
    address: str | None = None,
    has_truth: Callable[[int], bool] | None = None,
) -> Iterator[dict[str, str]]:
    """Rows of ``todo`` from ``workers`` Ray actors, in the order they finish (module docstring).

    ``make_worker(*worker_args)`` builds the object whose ``run(index)`` gives a row (``run._Worker``).
    ``has_truth(index)``: does that query have a true pose (its ``failed`` row is then a miss of every
    recall: ``results.failed_row``); default: none has.
    """
    ray = import_ray()
    started = not ray.is_initialized()
    with contextlib.ExitStack() as stack:
        if started:
            if address:
                join_cluster(ray, address)
            else:
                stack.enter_context(run_token())
                ray.init(
                    address="local",  # a new runtime even when a `ray start` cluster runs on this machine
                    num_cpus=workers,
                    include_dashboard=False,
                    log_to_driver=False,
                    object_store_memory=OBJECT_STORE_BYTES,
                )
        try:
            yield from _schedule(ray, todo, workers, make_worker, worker_args, has_truth)
        finally:
            if started:
                ray.shutdown()


@contextlib.contextmanager
def run_token() -> Iterator[None]:
    """``RAY_AUTH_TOKEN`` set to a fresh random token while the block runs (the processes a local runtime
    starts inherit it), unless the user set ``RAY_AUTH_TOKEN`` or ``RAY_AUTH_TOKEN_PATH``; the environment
    as it was afterwards. With a token in the environment Ray writes none to ``~/.ray/auth_token``."""
    if os.environ.get("RAY_AUTH_TOKEN") or os.environ.get("RAY_AUTH_TOKEN_PATH"):
        yield
        return
    os.environ["RAY_AUTH_TOKEN"] = secrets.token_hex(32)
    try:
        yield
    finally:
        os.environ.pop("RAY_AUTH_TOKEN", None)


def host_port(address: str) -> tuple[str, int] | None:
    """(host, port) of a cluster address ``host:port`` or ``ray://host:port``; None for ``auto`` / ``local``
    (Ray looks those up itself). ``BenchmarkError`` on any other form (a text without a port, a port that is
    not a number, another scheme)."""
    if address in ("auto", "local"):
        return None
    scheme, sep, rest = address.rpartition("://")
    host, _, port = rest.rpartition(":")
    if (sep and scheme != "ray") or not host.strip("[]") or not port.isdigit() or not 0 < int(port) < 65536:
        raise BenchmarkError(
            f"{parameter('ray_address', address)}: expected host:port (e.g. 10.0.0.5:6379), ray://host:port "
            "or auto"
        )
    return host.strip("[]"), int(port)


def check_address(address: str) -> tuple[str, int] | None:
    """``host_port``, and for a ``ray://`` address Ray's client installed (``grpc``, what Ray checks for):
    the ``[ray]`` extra does not install it, and Ray says so in a traceback."""
    target = host_port(address)
    if address.startswith("ray://") and importlib.util.find_spec("grpc") is None:
        raise BenchmarkError(
            f"{parameter('ray_address', address)}: a ray:// address needs Ray's client, which the [ray] "
            f"extra does not install: pip install 'ray[client]', or give the head's host:port "
            f"(e.g. {target[0]}:6379)"
        )
    return target


def auto_address(ray) -> str | None:
    """The ``host:port`` Ray's ``auto`` stands for, as Ray finds it (``RAY_ADDRESS``, the
    ``ray_current_cluster`` file the last ``ray start`` on this machine wrote, a running head's process), or
    None when Ray finds none (``ray.init`` then says so at once)."""
    try:
        return ray._private.services.canonicalize_bootstrap_address("auto")
    except (OSError, ValueError, AttributeError):  # no cluster, a malformed RAY_ADDRESS, another Ray
        return None


def join_cluster(ray, address: str) -> None:
    """``ray.init(address)``, after checking within ``CONNECT_TIMEOUT_S`` that something answers there
    (for ``auto``, at the address Ray finds for it); Ray's refusals in one line."""
    target = check_address(address)
    found = auto_address(ray) if address == "auto" else None
    if found is not None:
        target = host_port(found)
    if target is not None:
        try:
            socket.create_connection(target, timeout=CONNECT_TIMEOUT_S).close()
        except OSError as exc:
            where = f"{target[0]}:{target[1]}" + (_AUTO_FOUND if found else "")
            raise BenchmarkError(
                f"{parameter('ray_address', address)}: no Ray cluster answers at {where} "
                f"({exc.strerror or exc}); {_START_HINT}"
            ) from None
    auth_error = getattr(ray.exceptions, "AuthenticationError", ())  # Ray's token authentication
    try:
        ray.init(address=address, include_dashboard=False, log_to_driver=False)
    except (ConnectionError, ValueError, auth_error) as exc:
        hint = _START_HINT
        if os.environ.get("RAY_AUTH_MODE") != "token" and _token_available():
            # A head started where ~/.ray/auth_token exists (any local Ray runtime writes one) asks for
            # it, but Ray's clients send it only in token mode; Ray then reports a failed connection.
            hint = (
                "if the cluster uses Ray's token authentication (a head started where ~/.ray/auth_token "
                f"exists does), set RAY_AUTH_MODE=token; else {_START_HINT}"
            )
        said = _first_line(exc).rstrip(".")
        raise BenchmarkError(f"{parameter('ray_address', address)}: {said}; {hint}") from None


def _token_available() -> bool:
    """Does this machine hold a Ray authentication token (Ray's own places for it)?"""
    path = os.environ.get("RAY_AUTH_TOKEN_PATH") or Path.home() / ".ray" / "auth_token"
    return bool(os.environ.get("RAY_AUTH_TOKEN")) or Path(path).is_file()


def _schedule(ray, todo, workers, make_worker, worker_args, has_truth=None) -> Iterator[dict[str, str]]:
    threads = max(1, (os.cpu_count() or 1) // workers)  # numba threads per actor, as the process pool
    args_ref = ray.put(worker_args)  # shipped once; every actor reads the same copy
    actor_class = ray.remote(num_cpus=1, max_restarts=0)(_RayWorker)

    def new_actor():
        return actor_class.remote(make_worker, threads, args_ref)

    actors = [new_actor() for _ in range(min(workers, len(todo)))]
    queue = list(reversed(todo))
    deaths: dict[int, int] = {}
    pending: dict[Any, tuple[int, int]] = {}  # result ref -> (actor slot, query index)

    def submit(slot: int, index: int) -> None:
        pending[actors[slot].run.remote(index)] = (slot, index)

    for slot in range(len(actors)):
        submit(slot, queue.pop())
    try:
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1)
            ref = ready[0]
            slot, index = pending.pop(ref)
            try:
                row = ray.get(ref)
            except ray.exceptions.RayActorError as exc:  # the worker process died, not the query's error
                ray.kill(actors[slot], no_restart=True)
                actors[slot] = new_actor()
                deaths[index] = deaths.get(index, 0) + 1
                if deaths[index] <= RETRIES:
                    submit(slot, index)
                    continue
                reason = f"worker died {deaths[index]} times: {_first_line(exc)}"
                row = failed_row(index, reason, has_truth is not None and has_truth(index))
            except ray.exceptions.RayTaskError as exc:
                raise exc.as_instanceof_cause() from None
            if queue:
                submit(slot, queue.pop())
            yield row
    finally:
        for actor in actors:
            ray.kill(actor, no_restart=True)


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0][:200] if text else type(exc).__name__
