"""The corpus's fork mode: one process imports what a `vrsim` invocation imports, once, and
forks a child per invocation that runs `python -m vrsim_cli ARGS` from there.

    python tests/hostile/forkserver.py        (started by corpus.py --fork; not by hand)

A spawned `python -m vrsim_cli` spends most of a corpus case (~1-3 s on a loaded machine)
importing numpy, numba, trimesh, the scene and model modules and the writers; a forked
child starts with all of that in memory. Everything else is as in spawn mode:

- the child runs the package's `__main__` as `-m` does (`runpy.run_module(..., alter_sys=
  True)`, `sys.argv[0]` the snapshot's `vrsim_cli/__main__.py`, `sys.path[0]` the case
  folder), in the case folder, with stdin from /dev/null and stdout/stderr to pipes the
  server drains, in a new session, with the signal dispositions and environment a fresh
  interpreter has (the thread-count variables set here for a safe fork are put back);
- it exits as the interpreter would: `SystemExit` -> its code (None 0, an int, anything
  else printed and 1), an uncaught exception -> `sys.excepthook` prints the traceback and
  the code is 1, an uncaught KeyboardInterrupt -> the traceback, then death by SIGINT;
  then non-daemon threads are joined, atexit functions run and stdout is flushed (a
  failed flush gives 120);
- the server enforces the timeout (SIGKILL to the child's process group) and reads the
  child's exit status and rusage with `os.wait4`: its ru_maxrss is that child's own peak,
  which on Linux counts the pages it shares with the server from the fork on, so the
  server's own RSS is reported next to it;
- vrsim_cli is imported from the snapshot (PYTHONPATH, as in spawn mode; checked), and
  the kernel cache is the same on-disk cache (numba's dispatchers are imported but nothing
  is compiled or loaded here: each child loads or compiles its kernels as a spawned
  process does).

Protocol: one JSON request per line on stdin {"cwd", "args", "timeout"}, one JSON answer
per line on stdout {"code", "hang", "wall_s", "rss_mb", "stdout_bytes", "stderr_b64",
"server_rss_mb"}. The first line written is {"ready": ..., "modules": n, "rss_mb": x}.
"""

from __future__ import annotations

import os
import sys

# Before numpy (OpenBLAS starts its thread pool when it is loaded): a forked child of a
# multi-threaded process may deadlock on a lock some other thread held at the fork.
THREAD_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS",
               "NUMEXPR_NUM_THREADS", "VECLIB_MAXIMUM_THREADS")
_USER_ENV = {k: os.environ.get(k) for k in THREAD_VARS}
for _k in THREAD_VARS:
    os.environ[_k] = "1"

import base64  # noqa: E402
import json  # noqa: E402
import selectors  # noqa: E402
import signal  # noqa: E402
import time  # noqa: E402

# A fresh interpreter's dispositions (taken before any import could change them)
FRESH_SIGNALS = {s: signal.getsignal(s) for s in signal.valid_signals()
                 if s not in (signal.SIGKILL, signal.SIGSTOP)}

# Modules a `vrsim` invocation imports lazily, inside the function that needs them
# (`grep -rn "^ \+import\|^ \+from" vrsim_cli`): meshes, collision, validation, readers and
# writers. Imported after vrsim_cli's own modules, as in a run.
LAZY = ["jsonschema", "trimesh", "scipy.spatial", "scipy.linalg", "networkx", "fcl",
        "PIL.Image", "PIL.ImageDraw", "PIL.ImageFont", "PIL.GifImagePlugin",
        "foxglove", "foxglove.messages", "foxglove.mcap", "google.protobuf.descriptor_pb2",
        "google.protobuf.descriptor_pool", "google.protobuf.message_factory",
        "google.protobuf.json_format", "mcap.reader", "mcap_protobuf.decoder",
        "imageio.v2", "imageio_ffmpeg", "fcntl"]
SKIP = ("vrsim_cli.__main__", "vrsim_cli.tools.bench", "vrsim_cli.tools.plot",
        "vrsim_cli.tools.sweep_report", "vrsim_cli.tools.executors")


def rss_mb() -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return round(int(line.split()[1]) / 1024, 1)
    return 0.0


def preload() -> dict:
    """Import vrsim_cli (from the snapshot), every submodule of it, then the lazy ones."""
    import importlib
    import pkgutil

    import vrsim_cli
    import vrsim_cli.cli  # noqa: F401

    snapshot = os.environ.get("PYTHONPATH", "").split(os.pathsep)[0]
    if snapshot and not vrsim_cli.__file__.startswith(snapshot):
        raise SystemExit(f"vrsim_cli imported from {vrsim_cli.__file__}, not the snapshot "
                         f"{snapshot}")
    failed = []
    for info in pkgutil.walk_packages(vrsim_cli.__path__, "vrsim_cli."):
        if info.name.startswith(SKIP):
            continue
        try:
            importlib.import_module(info.name)
        except Exception as exc:  # an optional dependency missing: the child imports it
            failed.append(f"{info.name}: {exc!r}"[:200])
    for name in LAZY:
        try:
            importlib.import_module(name)
        except Exception as exc:
            failed.append(f"{name}: {exc!r}"[:200])
    threads = len(os.listdir("/proc/self/task"))
    if threads != 1:
        raise SystemExit(f"{threads} threads after the imports: forking is not safe")
    return {"vrsim_cli": vrsim_cli.__file__, "modules": len(sys.modules),
            "not_imported": failed, "rss_mb": rss_mb(),
            "open_fds": sorted(int(fd) for fd in os.listdir("/proc/self/fd"))}


def child(cwd: str, args: list, out_w: int, err_w: int, close: list) -> None:
    """In the forked child: become `python -m vrsim_cli ARGS` in `cwd`; never returns."""
    code = 1
    try:
        os.setsid()
        for s, handler in FRESH_SIGNALS.items():
            try:
                signal.signal(s, handler)
            except (OSError, ValueError, TypeError):
                pass
        signal.pthread_sigmask(signal.SIG_SETMASK, [])
        for key, value in _USER_ENV.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value
        null = os.open(os.devnull, os.O_RDONLY)
        os.dup2(null, 0)
        os.dup2(out_w, 1)
        os.dup2(err_w, 2)
        for fd in {null, out_w, err_w, *close}:
            if fd > 2:
                os.close(fd)
        os.chdir(cwd)
        sys.path[0] = os.getcwd()  # as `python -m` has it
    except BaseException as exc:  # the set-up failed: say so in the child's stderr
        os.write(2, f"forkserver: child set-up failed: {exc!r}\n".encode())
        os._exit(125)
    code = run_main(args)
    os._exit(code)


def run_main(args: list) -> int:
    """`python -m vrsim_cli ARGS`, with the interpreter's handling of how it ends."""
    import runpy
    import threading

    sys.argv = ["-m", *args]  # run_module sets argv[0] to the module's file, as -m does
    code = 0
    interrupted = False
    try:
        runpy.run_module("vrsim_cli", run_name="__main__", alter_sys=True)
    except SystemExit as exc:
        code = exit_code(exc.code)
    except KeyboardInterrupt:
        sys.excepthook(*sys.exc_info())
        interrupted = True
    except BaseException:
        sys.excepthook(*sys.exc_info())
        code = 1
    try:
        threading._shutdown()  # join non-daemon threads, as at interpreter exit
    except BaseException:
        pass
    import atexit

    atexit._run_exitfuncs()
    for stream, name in ((sys.stdout, "stdout"), (sys.stderr, "stderr")):
        try:
            stream.flush()
        except Exception as exc:
            if name == "stdout":
                os.write(2, f"Exception ignored in: <_io.TextIOWrapper name='<stdout>'>\n"
                            f"{exc!r}\n".encode())
                code = 120
    if interrupted:  # Python re-raises SIGINT with the default action
        signal.signal(signal.SIGINT, signal.SIG_DFL)
        os.kill(os.getpid(), signal.SIGINT)
    return code


def exit_code(code) -> int:
    if code is None:
        return 0
    if isinstance(code, int):
        return code & 0xFF
    try:
        sys.stderr.write(f"{code}\n")
    except Exception:
        pass
    return 1


def invoke(cwd: str, args: list, timeout: float, proto: list, proto_out) -> dict:
    """Fork a child for one invocation; wait for it (killing its group at the timeout)
    while draining its stdout and stderr."""
    out_r, out_w = os.pipe()
    err_r, err_w = os.pipe()
    sys.stdout.flush()
    sys.stderr.flush()
    start = time.perf_counter()
    pid = os.fork()
    if pid == 0:
        child(cwd, args, out_w, err_w, [out_r, err_r, *proto])
    os.close(out_w)
    os.close(err_w)
    proto_out.write(json.dumps({"pid": pid}) + "\n")  # the corpus kills it on SIGINT/SIGTERM
    proto_out.flush()
    pidfd = os.pidfd_open(pid)
    sel = selectors.DefaultSelector()
    chunks = {out_r: [], err_r: []}
    for fd in (out_r, err_r):
        os.set_blocking(fd, False)
        sel.register(fd, selectors.EVENT_READ)
    sel.register(pidfd, selectors.EVENT_READ)
    deadline = start + timeout
    hang = False
    exited = False
    open_pipes = 2

    def drain(limit: float) -> None:
        nonlocal exited, open_pipes
        while open_pipes or not exited:
            left = limit - time.perf_counter()
            if left <= 0:
                return
            for key, _ in sel.select(left):
                fd = key.fd
                if fd == pidfd:
                    exited = True
                    sel.unregister(pidfd)
                    continue
                try:
                    data = os.read(fd, 1 << 16)
                except BlockingIOError:
                    continue
                if data:
                    chunks[fd].append(data)
                else:
                    sel.unregister(fd)
                    open_pipes -= 1

    drain(deadline)  # like communicate(timeout): both pipes at EOF and the child gone
    if open_pipes or not exited:
        hang = True
        for kill in (lambda: os.killpg(pid, signal.SIGKILL), lambda: os.kill(pid, signal.SIGKILL)):
            try:
                kill()
            except ProcessLookupError:
                pass
        drain(time.perf_counter() + 10.0)  # what the killed group had written
    _, status, usage = os.wait4(pid, 0)
    wall = time.perf_counter() - start
    sel.close()
    for fd in (out_r, err_r, pidfd):
        os.close(fd)
    err = b"".join(chunks[err_r])
    return {"code": os.waitstatus_to_exitcode(status), "hang": hang, "wall_s": round(wall, 3),
            "rss_mb": round(usage.ru_maxrss / 1024, 1),  # KB on Linux
            "stdout_bytes": sum(map(len, chunks[out_r])),
            "stderr_b64": base64.b64encode(err).decode(), "server_rss_mb": rss_mb()}


def serve() -> None:
    # The protocol gets its own descriptors; 0 and 1 become /dev/null and stderr, so
    # nothing a child or an import prints can corrupt it.
    proto_in, proto_out = os.dup(0), os.dup(1)
    null = os.open(os.devnull, os.O_RDONLY)
    os.dup2(null, 0)
    os.close(null)
    os.dup2(2, 1)
    requests = os.fdopen(proto_in, "r", encoding="utf-8")
    answers = os.fdopen(proto_out, "w", encoding="utf-8")
    info = preload()
    answers.write(json.dumps({"ready": True, **info}) + "\n")
    answers.flush()
    for line in requests:
        request = json.loads(line)
        answer = invoke(request["cwd"], request["args"], request["timeout"],
                        [proto_in, proto_out], answers)
        answers.write(json.dumps(answer) + "\n")
        answers.flush()


if __name__ == "__main__":
    # `python -m` puts the working folder first (the corpus root: no vrsim_cli in it); a
    # child puts its case folder there. This script's folder must not be seen.
    sys.path[0] = os.getcwd()
    serve()
