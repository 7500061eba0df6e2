"""Where the jobs of a sweep or a regression run: this process, a local pool of worker
processes, or a Ray cluster. Every executor runs `jobs.execute` on the same pickled job
and so gives the same numbers bit for bit; only wall times differ.

Layer 7. The interface, shared by all three:

    executor.share(obj) -> handle       a large object many jobs need (a reference
                                        trajectory, a golden): sent to a worker once
    executor.run(items, on_done, should_stop)
                                        items: [(Job, handle or None)]; calls
                                        on_done(job, Outcome) in this process as each job
                                        finishes, in completion order
    executor.close()

- `Serial` (`--jobs 1`): in this process, one job after another; Ctrl-C stops the
  current run at its next frame.
- `LocalPool` (`--jobs N`, N > 1): N worker processes started once and reused for every
  job (no interpreter per run; a compiled kernel warms up once per worker). Each worker
  has its own pipe, so the parent always knows which job a worker is running: a worker
  that dies (a segfault in a native library, the OOM killer) fails exactly its own job,
  with the exit code, and is replaced. Workers come from a forkserver that has imported
  vrsim once, where the platform has one: fast to start, and nothing of the parent
  (threads, open files, signal handlers) leaks into them.
- `RayExecutor` (`--ray [ADDRESS]`): `ray.init()` locally or connected to a cluster;
  shared objects go through Ray's object store. Ray is optional (`pip install
  'vrsim-cli[ray]'`) and imported here only.
"""

from __future__ import annotations

import multiprocessing
import os
import signal
from collections import OrderedDict
from multiprocessing import connection

from vrsim_cli.errors import InputError
from vrsim_cli.tools import jobs as jobs_module
from vrsim_cli.tools.jobs import Job, Outcome, crashed

POLL_S = 0.2  # how often a waiting parent looks at should_stop
SHARED_PER_WORKER = 8  # shared objects a worker keeps; the oldest is dropped first


def default_jobs() -> int:
    """The cores this process may use."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def make_executor(jobs: int | None, ray_address: str | None | bool = None):
    """`Serial` for one job at a time, `LocalPool` for more, `RayExecutor` when
    `ray_address` is not None/False ("" or True: a local Ray; else the cluster's address)."""
    if ray_address not in (None, False):
        return RayExecutor(None if ray_address in ("", True) else ray_address, jobs)
    jobs = jobs or default_jobs()
    return Serial() if jobs <= 1 else LocalPool(jobs)


# ----------------------------------------------------------------------------- serial


class Serial:
    name = "serial"
    workers = 1

    def share(self, obj):
        return obj

    def run(self, items, on_done, should_stop=None):
        for job, shared in items:
            if should_stop is not None and should_stop():
                return
            outcome = jobs_module.execute(job, shared, should_stop)
            if outcome.status == "interrupted":
                return
            on_done(job, outcome)

    def close(self):
        pass


# ----------------------------------------------------------------------------- local pool


def _worker_main(conn) -> None:
    """A worker: jobs and shared objects come down the pipe, outcomes go back up."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent decides what Ctrl-C does
    shared: dict = {}
    while True:
        try:
            message = conn.recv()
        except (EOFError, OSError):
            return
        kind = message[0]
        if kind == "stop":
            return
        if kind == "share":
            shared[message[1]] = message[2]
        elif kind == "drop":
            shared.pop(message[1], None)
        elif kind == "job":
            job, handle = message[1], message[2]
            outcome = jobs_module.execute(job, shared.get(handle) if handle else None)
            conn.send(outcome)


def _context():
    """forkserver (preloaded with the worker's imports) where there is one, else spawn."""
    methods = multiprocessing.get_all_start_methods()
    if "forkserver" in methods:
        ctx = multiprocessing.get_context("forkserver")
        ctx.set_forkserver_preload(["vrsim_cli.tools.jobs", "vrsim_cli.loop",
                                    "vrsim_cli.tools.compare"])
        return ctx
    return multiprocessing.get_context("spawn")


class _Worker:
    def __init__(self, ctx):
        self.conn, child = ctx.Pipe()
        self.process = ctx.Process(target=_worker_main, args=(child,), daemon=True)
        self.process.start()
        child.close()
        self.job: Job | None = None
        self.has: OrderedDict = OrderedDict()  # shared handles the worker holds

    def send(self, message) -> None:
        self.conn.send(message)

    def stop(self, kill: bool = False) -> None:
        if kill:
            self.process.kill()
        else:
            try:
                self.send(("stop",))
            except OSError:
                pass
        self.process.join(timeout=5)
        if self.process.is_alive():
            self.process.kill()
            self.process.join()
        self.conn.close()


class LocalPool:
    name = "local"

    def __init__(self, jobs: int):
        self.workers = jobs
        self._ctx = _context()
        self._pool: list[_Worker] = []
        self._shared: dict = {}
        self._next = 0

    def share(self, obj):
        self._next += 1
        handle = f"s{self._next}"
        self._shared[handle] = obj
        return handle

    def _start(self, count: int) -> None:
        while len(self._pool) < min(self.workers, count):
            self._pool.append(_Worker(self._ctx))

    def _give(self, worker: _Worker, job: Job, handle) -> None:
        if handle is not None and handle not in worker.has:
            worker.send(("share", handle, self._shared[handle]))
            worker.has[handle] = True
            while len(worker.has) > SHARED_PER_WORKER:
                old, _ = worker.has.popitem(last=False)
                worker.send(("drop", old))
        if handle is not None:
            worker.has.move_to_end(handle)
        worker.job = job
        worker.send(("job", job, handle))

    def run(self, items, on_done, should_stop=None):
        pending = list(items)[::-1]  # pop() from the end takes them in order
        self._start(len(pending))
        busy: dict = {}  # worker -> (job, handle)
        while pending or busy:
            if should_stop is not None and should_stop():
                self.close(kill=True)
                return
            for worker in self._pool:
                if worker not in busy and pending:
                    job, handle = pending.pop()
                    try:
                        self._give(worker, job, handle)
                    except (OSError, EOFError):  # died while idle: replace, try again
                        pending.append((job, handle))
                        self._replace(worker)
                        break
                    busy[worker] = (job, handle)
            if not busy:
                continue
            waitables = {}
            for worker in busy:
                waitables[worker.conn] = worker
                waitables[worker.process.sentinel] = worker
            for ready in connection.wait(list(waitables), timeout=POLL_S):
                worker = waitables[ready]
                if worker not in busy:
                    continue  # its pipe and its sentinel were both ready
                job, _ = busy.pop(worker)
                outcome = None
                if ready is worker.conn:
                    try:
                        outcome = worker.conn.recv()
                    except (EOFError, OSError):
                        outcome = None
                if outcome is None:  # the process ended in the middle of the job
                    worker.process.join(timeout=5)
                    code = worker.process.exitcode
                    why = (f"killed by signal {-code}" if code is not None and code < 0
                           else f"exit code {code}")
                    outcome = crashed(job.key, f"the worker process died running this job "
                                               f"({why})")
                    self._replace(worker)
                worker.job = None
                on_done(job, outcome)

    def _replace(self, worker: _Worker) -> None:
        index = self._pool.index(worker)
        try:
            worker.stop(kill=True)
        except OSError:
            pass
        self._pool[index] = _Worker(self._ctx)

    def close(self, kill: bool = False):
        for worker in self._pool:
            worker.stop(kill=kill)
        self._pool = []


# ----------------------------------------------------------------------------- ray


def _ray_execute(job: Job, shared) -> Outcome:
    """The Ray task: Ray resolves `shared` (an ObjectRef passed at the top level) to the
    object itself, read from the node's object store."""
    return jobs_module.execute(job, shared)


class RayExecutor:
    name = "ray"

    def __init__(self, address: str | None, jobs: int | None):
        try:
            import ray
        except ImportError:
            raise InputError("--ray needs Ray: pip install 'vrsim-cli[ray]' (on this "
                             "machine and on every node of the cluster)") from None
        self.ray = ray
        self.started = False
        if not ray.is_initialized():
            kwargs = {"include_dashboard": False, "log_to_driver": False,
                      "configure_logging": False}
            if address is None:
                # A local Ray: --jobs caps its CPUs. (RAY_ADDRESS, when set, connects.)
                if jobs and not os.environ.get("RAY_ADDRESS"):
                    kwargs["num_cpus"] = jobs
            else:
                kwargs["address"] = address
            try:
                ray.init(**kwargs)
            except (ConnectionError, RuntimeError, ValueError) as exc:
                raise InputError(f"--ray {address or ''}: cannot start or reach Ray: "
                                 f"{exc}".replace("  ", " ")) from None
            self.started = True
        self.workers = max(1, int(ray.cluster_resources().get("CPU", 1)))
        # Retries cover a lost node or worker; a job that kills its worker every time is
        # reported after the last retry.
        self._remote = ray.remote(num_cpus=1, max_retries=2)(_ray_execute)

    def share(self, obj):
        return self.ray.put(obj)

    def run(self, items, on_done, should_stop=None):
        ray = self.ray
        pending = list(items)[::-1]
        running: dict = {}  # ObjectRef -> job
        limit = 2 * self.workers  # enough in flight to keep every CPU busy
        while pending or running:
            if should_stop is not None and should_stop():
                for ref in running:
                    ray.cancel(ref, force=True)
                return
            while pending and len(running) < limit:
                job, handle = pending.pop()
                running[self._remote.remote(job, handle)] = job
            done, _ = ray.wait(list(running), num_returns=1, timeout=POLL_S)
            for ref in done:
                job = running.pop(ref)
                try:
                    outcome = ray.get(ref)
                except Exception as exc:  # a lost worker or node, after the retries
                    outcome = crashed(job.key, f"Ray could not run this job: "
                                               f"{type(exc).__name__}: {exc}".splitlines()[0])
                on_done(job, outcome)

    def close(self, kill: bool = False):
        if self.started:
            self.ray.shutdown()


def describe(executor) -> str:
    """`in this process`, `on 2 worker processes`, `on Ray (8 CPUs)`."""
    if executor.name == "serial":
        return "in this process"
    if executor.name == "local":
        return f"on {executor.workers} worker processes"
    return f"on Ray ({executor.workers} CPUs)"


__all__ = ["LocalPool", "RayExecutor", "Serial", "default_jobs", "describe", "make_executor"]
