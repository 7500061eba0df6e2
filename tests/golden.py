"""Golden trajectories and pinned state hashes of the scenarios in `scenarios/`.

    python tests/golden.py            check every scenario against its golden (exit 1: not)
    python tests/golden.py --update   regenerate goldens and this platform's hash pins

For each `scenarios/NAME.yaml` the golden is `tests/golden/NAME.csv.gz`: the trajectory of
`vrsim run scenarios/NAME.yaml -o NAME.csv`, thinned to at most GOLDEN_SAMPLES sample times
(always the first and the last) and gzip-compressed deterministically (mtime 0, no file
name, level 9), so regenerating an unchanged scenario rewrites the very same bytes and a
changed one shows as changed CSV rows (`git diff` with the gzip textconv of
docs/regression.md). `tests/golden/hashes.json` pins the `state sha256` that `vrsim run`
prints, per platform (OS and machine): equal hashes mean bit-identical final states.

`tests/test_golden.py` reruns each scenario and compares it with its golden through
`vrsim_cli.compare` at GOLDEN_TOLERANCE (see there why that tolerance).
"""

from __future__ import annotations

import argparse
import gzip
import io
import json
import math
import platform
import sys
import tempfile
from pathlib import Path

from click.testing import CliRunner

from vrsim_cli.cli import cli
from vrsim_cli.tools.compare import Tolerance, TolerancePlan, compare, format_report
from vrsim_cli.tools.trajectory import read_trajectory

REPO = Path(__file__).resolve().parent.parent
SCENARIOS = REPO / "scenarios"
GOLDEN = REPO / "tests" / "golden"
HASHES = "hashes.json"
REGENERATE = "python tests/golden.py --update"

GOLDEN_SAMPLES = 21  # sample times kept per golden: compact, yet the whole run is covered

# On the platform that pinned the hashes a rerun is bit-identical (the hash test checks
# that). The golden comparison is for the rest: another CPU, libm or numpy build may round
# differently (e.g. SIMD sin/cos in the emitter), an error of ~1e-16 relative that the
# smooth scenarios carry forward about linearly: 2000 steps of a 10 m, 10 m/s scene give
# ~1e-12. 1e-9 (m, m/s, rad/s; and 1e-9 rad, 1e-9 relative) is a thousand times above
# that and a million times below the smallest change in physics worth a regression
# (a different integrator or dt moves the projectile by 7e-3 m).
GOLDEN_TOLERANCE = Tolerance(atol=1e-9, rtol=1e-9, angle_tol=1e-9)
# Scenarios whose dynamics amplify round-off (chaos, contact) need their own tolerance,
# stated and justified here: {"scenario name": Tolerance(...)}.
SCENARIO_TOLERANCE: dict = {
    # Rotation about the intermediate axis is unstable: one ulp more spin (5.0 ->
    # 5.000000000000001 rad/s) moves the orientation by 2.3e-8 rad and the angular velocity
    # by 4.6e-8 rad/s by t = 12 s. 1e-5 is 200 times that; halving dt, the smallest change
    # worth catching here, moves them by 2.4e-3 rad and 4.8e-3 rad/s, 240 times above it.
    # (Measured with `vrsim compare` on the perturbed runs, see docs/regression.md.)
    "dzhanibekov": Tolerance(atol=1e-5, rtol=0.0, angle_tol=1e-5),
    # A box tumbling down stairs: which corner lands first decides the rest of the fall,
    # so one ulp more launch speed (2.5 -> 2.5000000000000004 m/s) moves the box by 4.9e-5
    # m, its velocity by 2.7e-3 m/s, its spin by 1.7e-2 rad/s and its orientation by
    # 2.6e-4 rad. 0.1 (m, m/s, rad/s) and 0.01 rad are 6 to 40 times that; halving dt
    # moves them by 0.16 m, 0.84 m/s, 6.7 rad/s and 1.6 rad, above it (restitution 0.31
    # instead of 0.3: 0.46 m, 21 rad/s). The bit-identical rerun is the hash pin's job.
    "stairs": Tolerance(atol=0.1, rtol=0.0, angle_tol=0.01),
}


def platform_key() -> str:
    return f"{platform.system()}-{platform.machine()}"


def scenario_names(scenarios: Path = SCENARIOS) -> list[str]:
    return sorted(p.stem for p in scenarios.glob("*.yaml"))


def golden_path(name: str, golden: Path = GOLDEN) -> Path:
    return golden / f"{name}.csv.gz"


def run_scenario(scene: Path, out_csv: Path) -> str:
    """Run a scene through the `vrsim run` command to a CSV file; the printed state hash."""
    result = CliRunner().invoke(cli, ["run", str(scene), "-o", str(out_csv)],
                                catch_exceptions=False)
    if result.exit_code != 0:
        raise RuntimeError(f"vrsim run {scene} exited {result.exit_code}:\n{result.output}")
    lines = [ln for ln in result.stdout.splitlines() if ln.startswith("state sha256:")]
    return lines[-1].split(":", 1)[1]


def thin_csv(text: str, keep: int = GOLDEN_SAMPLES) -> str:
    """The CSV with at most `keep` evenly strided sample times, always the first and last."""
    header, *rows = text.splitlines(keepends=True)
    times = sorted({float(r.split(",", 1)[0]) for r in rows})
    stride = max(1, math.ceil((len(times) - 1) / max(keep - 1, 1)))
    kept = set(times[::stride]) | {times[-1]} if times else set()
    return header + "".join(r for r in rows if float(r.split(",", 1)[0]) in kept)


def gzip_bytes(data: bytes) -> bytes:
    """gzip that depends on the data only: mtime 0, no file name in the header."""
    buffer = io.BytesIO()
    with gzip.GzipFile(filename="", mode="wb", fileobj=buffer, compresslevel=9,
                       mtime=0) as f:
        f.write(data)
    return buffer.getvalue()


def load_hashes(golden: Path = GOLDEN) -> dict:
    path = golden / HASHES
    return json.loads(path.read_text()) if path.exists() else {}


def check(name: str, run_csv: Path, golden: Path = GOLDEN):
    """(ok, report lines) of a scenario's run against its golden."""
    path = golden_path(name, golden)
    if not path.exists():
        return False, [f"{name}: no golden file {path.name}; create it with `{REGENERATE}`"]
    tol = SCENARIO_TOLERANCE.get(name, GOLDEN_TOLERANCE)
    report = compare(read_trajectory(run_csv), read_trajectory(path), TolerancePlan(tol))
    return report.ok, [f"{name}:"] + ["  " + ln for ln in format_report(report)]


def update(names: list[str], scenarios: Path = SCENARIOS, golden: Path = GOLDEN,
           say=print) -> None:
    """Rerun `names`, rewrite their goldens and this platform's hashes; say what changed."""
    golden.mkdir(parents=True, exist_ok=True)
    hashes = load_hashes(golden)
    pins = hashes.setdefault(platform_key(), {})
    with tempfile.TemporaryDirectory() as tmp:
        for name in names:
            out = Path(tmp) / f"{name}.csv"
            digest = run_scenario(scenarios / f"{name}.yaml", out)
            data = gzip_bytes(thin_csv(out.read_text("utf-8")).encode("utf-8"))
            path = golden_path(name, golden)
            if path.exists() and path.read_bytes() == data:
                say(f"{name}: golden unchanged")
            else:
                if path.exists():  # a summary of the change, for the commit message
                    ok, lines = check(name, out, golden)
                    say("\n".join(lines))
                path.write_bytes(data)
                say(f"{name}: wrote {path.relative_to(golden.parent.parent)} "
                    f"({len(data)} bytes)")
            if pins.get(name) != digest:
                say(f"{name}: state sha256 {pins.get(name, '(none)')} -> {digest}")
            pins[name] = digest
    known = set(scenario_names(scenarios))
    for platform_pins in hashes.values():
        for stale in sorted(set(platform_pins) - known):
            del platform_pins[stale]
            say(f"{stale}: no such scenario any more; pin removed")
    for path in sorted(golden.glob("*.csv.gz")):
        if path.name[: -len(".csv.gz")] not in known:
            path.unlink()
            say(f"{path.name}: no such scenario any more; golden removed")
    (golden / HASHES).write_text(json.dumps(hashes, indent=2, sort_keys=True) + "\n")


def main(argv: list[str] | None = None, scenarios: Path = SCENARIOS,
         golden: Path = GOLDEN) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--update", action="store_true",
                        help="rewrite the goldens and this platform's hash pins")
    parser.add_argument("names", nargs="*", help="scenario names (default: all)")
    args = parser.parse_args(argv)
    names = args.names or scenario_names(scenarios)
    unknown = sorted(set(names) - set(scenario_names(scenarios)))
    if unknown:
        print(f"no such scenario: {', '.join(unknown)}", file=sys.stderr)
        return 2
    if args.update:
        update(names, scenarios, golden)
        return 0
    failed = False
    pins = load_hashes(golden).get(platform_key(), {})
    with tempfile.TemporaryDirectory() as tmp:
        for name in names:
            out = Path(tmp) / f"{name}.csv"
            digest = run_scenario(scenarios / f"{name}.yaml", out)
            ok, lines = check(name, out, golden)
            print("\n".join(lines))
            if pins.get(name) != digest:
                ok = False
                print(f"  state sha256:{digest} differs from the pin "
                      f"{pins.get(name, '(none)')} for {platform_key()}")
            failed |= not ok
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
