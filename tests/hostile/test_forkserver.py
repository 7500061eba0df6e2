"""The corpus's fork mode sees what spawn mode sees: a stand-in `vrsim_cli` package whose
`__main__` does each thing a hostile invocation can end with (exit codes, SystemExit with
a message, an uncaught exception, KeyboardInterrupt, a signal, a hang, a grandchild that
keeps the pipes open, threads, atexit, memory) is run both ways, and the results the
corpus checks must be the same."""

from __future__ import annotations

import sys
import textwrap
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))
import corpus  # noqa: E402

MAIN = textwrap.dedent('''
    import atexit, os, signal, subprocess, sys, threading, time
    what = sys.argv[1]
    if what == "ok":
        print("hello")
    elif what == "exit3":
        sys.exit(3)
    elif what == "exit-text":
        sys.exit("a message")
    elif what == "raise":
        raise ValueError("boom")
    elif what == "keyboard":
        raise KeyboardInterrupt
    elif what == "sigterm":
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(5)
    elif what == "sleep":
        time.sleep(60)
    elif what == "grandchild":  # exits at once, but a grandchild holds stdout open
        subprocess.Popen(["sleep", "60"])
    elif what == "stdin":
        sys.stderr.write(f"stdin {sys.stdin.read()!r}\\n")
    elif what == "where":
        sys.stderr.write(f"{sys.argv} {sys.path[0]} {os.getcwd()} {__name__} "
                         f"{sys.modules['__main__'].__file__}\\n")
    elif what == "signals":
        sys.stderr.write(" ".join(str(signal.getsignal(s)) for s in (
            signal.SIGINT, signal.SIGTERM, signal.SIGPIPE, signal.SIGCHLD, signal.SIGXFSZ))
            + f" mask {sorted(signal.pthread_sigmask(signal.SIG_BLOCK, []))}\\n")
    elif what == "env":
        fds = {}
        for fd in os.listdir("/proc/self/fd"):
            try:
                target = os.readlink(f"/proc/self/fd/{fd}")
                if "/rss-" not in target:  # GNU time's -o file, open in spawn mode
                    fds[int(fd)] = target.split("[")[0]
            except OSError:  # listdir's own
                pass
        sys.stderr.write(f"{os.environ.get('OPENBLAS_NUM_THREADS')} "
                         f"{os.getpgid(0) == os.getsid(0)} {sorted(fds.items())}\\n")
    elif what == "thread":
        threading.Thread(target=lambda: (time.sleep(0.3), print("late"))).start()
    elif what == "atexit":
        atexit.register(lambda: sys.stderr.write("bye\\n"))
    elif what == "memory":
        block = bytearray(300 * 2 ** 20)
        block[::4096] = b"x" * len(block[::4096])
    ''')
CASES = ["ok", "exit3", "exit-text", "raise", "keyboard", "sigterm", "sleep", "grandchild",
         "stdin", "where", "signals", "env", "thread", "atexit", "memory"]


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    root = tmp_path_factory.mktemp("corpus")
    package = root / "snapshot" / "vrsim_cli"
    package.mkdir(parents=True)
    (package / "__init__.py").write_text("")
    (package / "cli.py").write_text("")
    (package / "__main__.py").write_text(MAIN)
    (root / "cases" / "case-x" / "w").mkdir(parents=True)
    old = corpus.SNAPSHOT
    corpus.SNAPSHOT = root / "snapshot"
    yield root
    corpus.SNAPSHOT = old
    for server in corpus.SERVERS.values():
        server.stop()
    corpus.SERVERS.clear()


@pytest.mark.parametrize("what", CASES)
def test_fork_mode_agrees_with_spawn_mode(root, what):
    folder = root / "cases" / "case-x" / "w"
    # the hangs are cut at 3 s; the rest gets room for a loaded machine
    timeout = 3.0 if what in ("sleep", "grandchild") else 60.0
    spawned = corpus.run_invocation(folder, [what], timeout, fork=False)
    forked = corpus.run_invocation(folder, [what], timeout, fork=True)
    assert "fallback" not in forked
    for key in ("code", "hang", "traceback", "stdout_bytes"):
        assert spawned[key] == forked[key], (key, spawned, forked)
    # what the process said is the same too, but for the last frames of a traceback
    # (runpy's, from the fork server) and the memory figures
    if not spawned["traceback"]:
        assert spawned["stderr"] == forked["stderr"]
    else:
        assert spawned["stderr"].splitlines()[-1] == forked["stderr"].splitlines()[-1]
    if what == "memory":
        assert spawned["rss_mb"] >= 300 and forked["rss_mb"] >= 300
    expected = {"ok": 0, "exit3": 3, "exit-text": 1, "raise": 1, "keyboard": -2,
                "sigterm": -15, "sleep": -9}
    assert spawned["code"] == expected.get(what, 0), spawned
