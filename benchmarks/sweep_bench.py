"""Throughput of `vrsim sweep`: its overhead per run beyond the simulation, and how it
scales with --jobs (issue 18: <= 10 ms per run for 100 variants of a small scene; >= 0.8
of linear scaling on an idle machine).

    python benchmarks/sweep_bench.py                 # both measurements, ~1-2 minutes
    python benchmarks/sweep_bench.py --only overhead
    python benchmarks/sweep_bench.py --only scaling --jobs 2

Overhead: 100 variants of scenarios/projectile.yaml (a point mass, 1.5 s; dt x integrator
x launch speed) against a computed reference, through the same functions the command
uses (plan_sweep, run_sweep, write_report). Overhead per run = (planning + running) x
jobs / runs - the mean simulation time of a run (the loop's own wall time, `wall_s` in
the table). Also in CPU time, which a busy machine disturbs much less: the CPU time of
this process (planning, the parent's share) plus the workers' CPU time in each job
outside its loop, per run (the loop's CPU time, `cpu_s`, includes the recording).
Planning (every variant validated and compiled), shipping the job, unpickling the model,
the error measurement and the table rows count as overhead (recording the samples too,
in the wall-time figure); the report (sweep.md and the plot, once per sweep) is timed
apart.

Scaling: the same 2 x jobs runs of a heavier scene (scenarios/bounce.yaml, ~1.5 s each)
with --jobs 1 and --jobs N; efficiency = T(1) / (N T(N)). Because this machine may be
shared, the script first measures what the cores give to N plain busy processes
(`capacity`: 1.0 on an idle machine) and prints the load average before and after: an
efficiency measured at low capacity says more about the neighbours than about vrsim.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

from vrsim_cli.tools import sweep
from vrsim_cli.tools.executors import LocalPool, Serial

REPO = Path(__file__).resolve().parent.parent


def _busy(seconds: float, out) -> None:
    """Pure-Python arithmetic for `seconds` of wall time; reports iterations done."""
    end = time.perf_counter() + seconds
    n, x = 0, 0.0
    while time.perf_counter() < end:
        for _ in range(1000):
            x = x * 1.0000001 + 1.0
        n += 1
    out.put(n)


def capacity(jobs: int, seconds: float = 2.0) -> float:
    """Work done by `jobs` busy processes at once over `jobs` times that of one alone:
    1.0 when the machine has `jobs` idle cores."""
    ctx = multiprocessing.get_context("spawn")

    def run(count):
        q = ctx.Queue()
        procs = [ctx.Process(target=_busy, args=(seconds, q)) for _ in range(count)]
        for p in procs:
            p.start()
        total = sum(q.get() for _ in procs)
        for p in procs:
            p.join()
        return total

    alone = run(1)
    return run(jobs) / (jobs * alone)


def _plan(scene: Path, sets: list[str], reference: str):
    pairs, _ = sweep.parse_reference((reference,))
    return sweep.plan_sweep([str(scene)], [sweep.parse_setting(s) for s in sets], pairs, None)


def overhead(executor_name: str, jobs: int, quick: bool = False) -> dict:
    scene = REPO / "scenarios" / "projectile.yaml"
    sets = ["dt=0.01,0.005,0.004,0.0025,0.002", "integrator=euler,symplectic-euler,rk4,verlet",
            "bodies.ball.velocity=[7.07, 7.07, 0],[5, 9, 0],[9, 5, 0],[3, 3, 0],[6, 6, 1]"]
    if quick:  # 8 variants: that the script runs, not a measurement (tests/test_benchmarks)
        sets = ["dt=0.01,0.005", "integrator=euler,rk4",
                "bodies.ball.velocity=[7.07, 7.07, 0],[5, 9, 0]"]
    reference = "integrator=rk4 dt=0.01 bodies.ball.velocity=[7.07,7.07,0]"
    executor = Serial() if jobs == 1 else LocalPool(jobs)
    outcomes = []
    with tempfile.TemporaryDirectory() as tmp:
        t0, c0 = time.perf_counter(), time.process_time()
        plan = _plan(scene, sets, reference)
        t1 = time.perf_counter()
        try:
            result = sweep.run_sweep(plan, Path(tmp) / "out", executor,
                                     on_run=lambda run, outcome: outcomes.append(outcome))
        finally:
            executor.close()
        t2, c2 = time.perf_counter(), time.process_time()
        sweep.write_report(plan, Path(tmp) / "out", executor_name)
        t3 = time.perf_counter()
        _, rows = sweep.read_rows(Path(tmp) / "out" / sweep.RUNS_CSV)
    runs = [r for r in rows if r["role"] == "run"]
    assert len(runs) == (8 if quick else 100), f"{len(runs)} runs"
    assert all(r["status"] == "ok" for r in runs), "a run failed"
    sim = [float(r["wall_s"]) for r in rows]  # the reference's simulation counts too
    n = len(runs)
    core_s = (t2 - t0) * jobs  # core time the sweep held
    # CPU time, which other work on the machine barely changes: this process's, plus (on
    # a pool) what the workers spent in each job beyond its loop
    sim_cpu = sum(o.cpu_s for o in outcomes)
    parent_cpu = c2 - c0
    if jobs == 1:
        cpu_overhead = parent_cpu - sim_cpu
    else:
        cpu_overhead = parent_cpu + sum(o.task_cpu_s - o.cpu_s for o in outcomes)
    return {"executor": executor_name, "jobs": jobs, "runs": n, "plan_s": t1 - t0,
            "run_phase_s": t2 - t1, "report_s": t3 - t2,
            "simulation_s_total": sum(sim), "simulation_ms_mean": 1e3 * statistics.mean(sim),
            "overhead_ms_per_run": 1e3 * (core_s - sum(sim)) / n,
            "cpu_overhead_ms_per_run": 1e3 * cpu_overhead / n,
            "simulation_cpu_ms_mean": 1e3 * sim_cpu / len(outcomes),
            "overhead_ms_per_run_with_report": 1e3 * ((t3 - t0) * jobs - sum(sim)) / n,
            "done": result.done}


def scaling(jobs: int) -> dict:
    scene = REPO / "scenarios" / "bounce.yaml"
    count = 2 * jobs
    values = ",".join(str(0.6 + 0.02 * i) for i in range(count))
    sets = [f"bodies.ball.material.restitution={values}"]
    plan = sweep.plan_sweep([str(scene)], [sweep.parse_setting(s) for s in sets], [], None)
    times = {}
    for n in (1, jobs):
        executor = Serial() if n == 1 else LocalPool(n)
        with tempfile.TemporaryDirectory() as tmp:
            start = time.perf_counter()
            try:
                sweep.run_sweep(plan, Path(tmp) / "out", executor)
            finally:
                executor.close()
            times[n] = time.perf_counter() - start
    return {"jobs": jobs, "runs": count, "t1_s": times[1], "tn_s": times[jobs],
            "speedup": times[1] / times[jobs],
            "efficiency": times[1] / (jobs * times[jobs])}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--only", choices=["overhead", "scaling"])
    parser.add_argument("--jobs", type=int, default=min(2, os.cpu_count() or 1))
    parser.add_argument("--json", action="store_true", help="one JSON object on stdout")
    parser.add_argument("--quick", action="store_true", help="8 variants and short capacity "
                        "probes: checks that the script works (seconds), measures nothing")
    args = parser.parse_args(argv)
    probe = 0.2 if args.quick else 2.0
    out = {"load_average_before": [round(x, 2) for x in os.getloadavg()],
           "cores": os.cpu_count()}
    out["capacity"] = round(capacity(args.jobs, probe), 3)
    if args.only in (None, "overhead"):
        out["overhead"] = [overhead("serial", 1, args.quick)] + (
            [overhead("pool", args.jobs, args.quick)] if args.jobs > 1 else [])
    if args.only in (None, "scaling"):
        out["capacity_after_overhead"] = round(capacity(args.jobs, probe), 3)
        out["scaling"] = scaling(args.jobs)
        out["capacity_after_scaling"] = round(capacity(args.jobs, probe), 3)
    out["load_average_after"] = [round(x, 2) for x in os.getloadavg()]
    if args.json:
        print(json.dumps(out, indent=2))
        return 0
    print(f"load average before {out['load_average_before']}, after "
          f"{out['load_average_after']}; {out['cores']} cores; capacity for {args.jobs} "
          f"busy processes {out['capacity']} (1.0: idle)")
    for o in out.get("overhead", []):
        print(f"overhead {o['executor']} (--jobs {o['jobs']}): {o['runs']} runs, plan "
              f"{o['plan_s']:.3f} s, runs {o['run_phase_s']:.3f} s, simulation mean "
              f"{o['simulation_ms_mean']:.2f} ms -> {o['overhead_ms_per_run']:.2f} ms per run "
              f"beyond the simulation ({o['overhead_ms_per_run_with_report']:.2f} ms with the "
              f"report, {o['report_s']:.3f} s); in CPU time {o['cpu_overhead_ms_per_run']:.2f} "
              f"ms per run beyond {o['simulation_cpu_ms_mean']:.2f} ms of loop CPU time")
    if "scaling" in out:
        s = out["scaling"]
        print(f"scaling: {s['runs']} bounce runs, --jobs 1 {s['t1_s']:.2f} s, --jobs "
              f"{s['jobs']} {s['tn_s']:.2f} s: speedup {s['speedup']:.2f}, efficiency "
              f"{s['efficiency']:.2f} (capacity before/after: "
              f"{out['capacity_after_overhead']}/{out['capacity_after_scaling']})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
