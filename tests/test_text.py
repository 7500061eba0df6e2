"""text.py: significant digits, wall times for people, and the progress bar (drawn only on a
terminal, after ~2 s, and never fatal to the work it reports on)."""

from __future__ import annotations

import io
import re

import pytest

from vrsim_cli import text
from vrsim_cli.text import Progress, duration, significant


@pytest.mark.parametrize("x, shown", [
    (5.93, "5.9"), (0.0123, "0.012"), (1234.0, "1200"), (0.0996, "0.10"), (9.96, "10"),
    (1.0, "1.0"), (0.05, "0.050"), (250.0, "250"), (-3.44, "-3.4"), (0.0, "0"),
    (1.5e-8, "1.5e-08"), (2.0e10, "2.0e+10")])
def test_two_significant_digits(x, shown):
    assert significant(x) == shown
    if x and 1e-6 <= abs(x) < 1e9:  # the text reads back as x to two digits
        assert float(shown) == pytest.approx(x, rel=0.05)


@pytest.mark.parametrize("seconds, shown", [
    (0.0123, "12.3 ms"), (0.25, "250 ms"), (1.0, "1 s"), (10.1, "10.1 s"),
    (10.1e0 * 1000 / 1000, "10.1 s"), (125.0, "2 min 05 s"), (3725.0, "1 h 02 min")])
def test_durations_read_as_people_write_them(seconds, shown):
    assert duration(seconds) == shown
    assert "e+" not in duration(10.1) and "e+" not in duration(1.01e4)


class Terminal(io.StringIO):
    def isatty(self):
        return True


class Clock:
    def __init__(self):
        self.now = 100.0

    def __call__(self):
        return self.now


def test_the_bar_waits_two_seconds_then_shows_the_time_left():
    out, clock = Terminal(), Clock()
    bar = Progress(10.0, stream=out, clock=clock)
    clock.now += 1.9
    bar.update(1.9, "t = 1.9 / 10 s")
    assert out.getvalue() == ""  # short work shows nothing
    clock.now += 2.1  # 4 s in, 40 % done: 6 s left at this rate
    bar.update(4.0, "t = 4 / 10 s")
    line = out.getvalue()
    assert line.startswith("\r[########            ]  40%  t = 4 / 10 s, 6 s left")
    clock.now += 0.05  # redrawn at most every 0.2 s
    bar.update(4.1)
    assert out.getvalue() == line
    bar.clear()
    assert out.getvalue().endswith("\r" + " " * (len(line) - 1) + "\r")


@pytest.mark.parametrize("stream", [io.StringIO(), None, "closed"])
def test_no_bar_off_a_terminal_or_without_stderr(stream, monkeypatch):
    if stream == "closed":
        stream = Terminal()
        stream.close()  # isatty and write raise ValueError on a closed file
    monkeypatch.setattr("sys.stderr", stream)
    clock = Clock()
    bar = Progress(1.0, clock=clock)
    clock.now += 5
    bar.update(0.5, "x")
    bar.clear()
    assert not bar.enabled


def test_a_stream_that_breaks_mid_run_switches_the_bar_off():
    out, clock = Terminal(), Clock()
    bar = Progress(1.0, stream=out, clock=clock)
    clock.now += 3
    out.close()
    bar.update(0.5)  # no exception: the work goes on
    assert not bar.enabled


@pytest.fixture
def terminal(monkeypatch):
    """stderr counts as a terminal and the bar shows at once (CliRunner's stderr is not one)."""
    monkeypatch.setattr(text, "_is_terminal", lambda stream: True)
    monkeypatch.setattr(text, "PROGRESS_AFTER_S", 0.0)


RUN = """
vrsim: 1
name: drop
duration: 1.0
frame_rate: 50
dt: 0.01
bodies: [{name: ball, mass: 1, position: [0, 10, 0]}]
"""


def test_run_shows_simulated_time_real_time_factor_and_time_left(invoke, write_scene, tmp_path,
                                                                   terminal):
    result = invoke("run", write_scene(RUN), "-o", tmp_path / "o.csv")
    assert result.exit_code == 0, result.output
    assert "\r[" in result.stderr and " / 1 s, " in result.stderr
    assert "x real time" in result.stderr
    assert result.stderr.endswith("\r")  # erased before the summary
    assert "\r" not in result.stdout


@pytest.mark.parametrize("flag", ["-q", "--json"])
def test_quiet_and_json_runs_show_no_bar(invoke, write_scene, tmp_path, terminal, flag):
    result = invoke("run", write_scene(RUN), "-o", tmp_path / "o.csv", flag)
    assert result.exit_code == 0 and "\r" not in result.stderr


def test_a_run_with_stderr_closed_still_runs(write_scene, tmp_path):
    """`vrsim run ... 2>&-`: Python starts with sys.stderr None; nothing may break."""
    import subprocess
    import sys

    out = tmp_path / "o.csv"
    code = ("import sys; assert sys.stderr is None; from vrsim_cli.cli import main; "
            f"sys.argv = ['vrsim', 'run', {str(write_scene(RUN))!r}, '-o', {str(out)!r}]; "
            "main()")
    done = subprocess.run(["bash", "-c", f'"{sys.executable}" -c "$0" 2>&-', code],
                          capture_output=False, stdout=subprocess.PIPE, timeout=300)
    assert done.returncode == 0
    assert b"drop: simulated 1 s" in done.stdout and out.exists()


def test_sweep_lines_say_wall_times_as_people_do():
    """The papercut: a 10 s run was '1.01e+04 ms'; one step was '1 steps'."""
    from types import SimpleNamespace

    from vrsim_cli.tools.jobs import Outcome
    from vrsim_cli.tools.sweep import progress_line

    run = SimpleNamespace(label="bounce dt=0.001", role="run")
    line = progress_line(run, Outcome("k", "ok", steps=1, wall_s=10.1), 3, 24)
    assert line == "[3/24] bounce dt=0.001: ok, 1 step, 10.1 s"
    line = progress_line(run, Outcome("k", "ok", steps=500, wall_s=0.0123), 3, 24)
    assert line == "[3/24] bounce dt=0.001: ok, 500 steps, 12.3 ms"


def test_validate_names_the_impact_mode_and_why(invoke, write_scene):
    """validate's impact-mode reason (it once read '1 dynamic bodies'; since `auto` is
    the compiled step for every scene it names that)."""
    scene = write_scene("""
        vrsim: 1
        duration: 0.1
        collision: {}
        bodies:
          - {name: ball, mass: 1, shape: {type: sphere, radius: 0.1}, position: [0, 1, 0]}
          - {name: floor, type: static, shape: {type: plane, normal: [0, 1, 0]}}
        """)
    result = invoke("validate", scene)
    assert result.exit_code == 0, result.output
    assert "stepped impacts (auto: the compiled contact step, for every scene)" in \
        result.stdout


def test_real_time_factors_have_two_significant_digits():
    from vrsim_cli.tools.run_report import format_run

    summary = {"scene": "s", "simulated_s": 1.0, "steps": 10, "dt_s": 0.1, "wall_s": 81.3,
               "realtime_factor": 1.0 / 81.3, "output": None, "state_sha256": "0"}
    assert ", 0.012x real time" in format_run(summary, False, False)[0]  # was 0.0x
    summary["realtime_factor"] = 1234.5
    assert ", 1200x real time" in format_run(summary, False, False)[0]


def test_sweep_shows_runs_done_and_time_left(invoke, write_scene, tmp_path, terminal):
    scene = write_scene(RUN)
    result = invoke("sweep", scene, "--set", "dt=0.01,0.005", "--jobs", "1", "-o",
                    tmp_path / "sweep")
    assert result.exit_code == 0, result.output
    assert "\r[" in result.stderr and "/2 runs" in result.stderr and " left" in result.stderr
    assert "\r" not in result.stdout  # the run lines and summary stay clean


def test_bench_redraws_its_bar_while_a_problem_runs(monkeypatch, terminal):
    """A bench problem can take a minute: the bar moves in between (the ticker thread)."""
    import time as clock

    from vrsim_cli.tools.bench import report


    def slow(names, quick, peers, repeats, on_progress):
        on_progress(0, 2, "projectile (vrsim), 1/2")
        clock.sleep(1.2)  # the ticker redraws every 0.5 s
        on_progress(1, 2, "bounce (vrsim), 2/2")
        clock.sleep(0.6)  # (a call within 0.2 s of the last drawing is drawn by the ticker)
        raise KeyboardInterrupt  # stop before writing a report

    monkeypatch.setattr(report, "run_bench", lambda *a, **k: slow(*a, **k))
    from click.testing import CliRunner

    from vrsim_cli.cli import cli

    shown = CliRunner().invoke(cli, ["bench", "--quick"]).stderr
    assert shown.count("projectile (vrsim), 1/2") >= 2  # redrawn while it ran
    assert "50%  bounce (vrsim), 2/2" in shown and " left" in shown
    assert re.search(r"\r +\rinterrupted\n$", shown)  # the bar erased before the message


@pytest.mark.parametrize("command", [["sweep", "{scene}", "--set", "dt=0.01,0.005", "--jobs",
                                      "1", "-o", "{out}"],
                                     ["validate", "--json", "{scene}"]])
def test_sweep_and_validate_with_stderr_closed(write_scene, tmp_path, command):
    import subprocess
    import sys

    args = [a.format(scene=write_scene(RUN), out=tmp_path / "sweep") for a in command]
    code = ("import sys; assert sys.stderr is None; from vrsim_cli.cli import main; "
            f"sys.argv = ['vrsim'] + {args!r}; main()")
    done = subprocess.run(["bash", "-c", f'"{sys.executable}" -c "$0" 2>&-', code],
                          stdout=subprocess.PIPE, timeout=300)
    assert done.returncode == 0 and done.stdout
