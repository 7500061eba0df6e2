"""Every scenario against its golden trajectory and its pinned state hash (tests/golden.py).

A scenario without a golden fails with the command that makes one; regenerating is a
deliberate act (`python tests/golden.py --update`, docs/regression.md).
"""

from __future__ import annotations

import gzip
import shutil

import pytest

import golden
from conftest import SCENARIOS

NAMES = golden.scenario_names()


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """name -> two runs of the scenario through `vrsim run`: [(state hash, CSV path)] * 2."""
    out = {}
    folder = tmp_path_factory.mktemp("golden-runs")
    for name in NAMES:
        out[name] = []
        for i in range(2):
            csv = folder / f"{name}-{i}.csv"
            out[name].append((golden.run_scenario(SCENARIOS / f"{name}.yaml", csv), csv))
    return out


def test_there_are_scenarios():
    assert NAMES, f"no scenarios in {SCENARIOS}"


@pytest.mark.parametrize("name", NAMES)
def test_scenario_matches_its_golden(name, runs):
    path = golden.golden_path(name)
    assert path.exists(), (f"scenario '{name}' has no golden trajectory {path}: "
                           f"run `{golden.REGENERATE}` and review the new file")
    ok, lines = golden.check(name, runs[name][0][1])
    assert ok, "\n".join(lines) + (f"\nIf this change in the numbers is intended, run "
                                   f"`{golden.REGENERATE}` and commit the goldens.")


@pytest.mark.parametrize("name", NAMES)
def test_two_runs_give_the_same_hash_and_the_same_bytes(name, runs):
    (hash1, csv1), (hash2, csv2) = runs[name]
    assert hash1 == hash2
    assert csv1.read_bytes() == csv2.read_bytes()


@pytest.mark.parametrize("name", NAMES)
def test_state_hash_equals_the_pin_for_this_platform(name, runs):
    pins = golden.load_hashes().get(golden.platform_key(), {})
    assert name in pins, (f"no pinned state hash for scenario '{name}' on "
                          f"{golden.platform_key()}: run `{golden.REGENERATE}`")
    assert runs[name][0][0] == pins[name], (
        f"'{name}' no longer reproduces its pinned final state bit for bit on "
        f"{golden.platform_key()}; if intended, run `{golden.REGENERATE}`")


def test_no_golden_without_a_scenario():
    stale = sorted(p.name for p in golden.GOLDEN.glob("*.csv.gz")
                   if p.name[: -len(".csv.gz")] not in NAMES)
    assert not stale, f"goldens of removed scenarios: {stale}; run `{golden.REGENERATE}`"


def test_gzip_is_deterministic_with_no_name_and_no_time():
    data = b"t,entity\n0.0,ball\n"
    blob = golden.gzip_bytes(data)
    assert blob == golden.gzip_bytes(data) and gzip.decompress(blob) == data
    # RFC 1952 header: FLG byte 3 has no FNAME bit (0x08); MTIME bytes 4-7 are zero
    assert blob[3] & 0x08 == 0 and blob[4:8] == b"\0\0\0\0"


def test_thinning_keeps_first_last_and_at_most_the_limit():
    header = "t,entity,x\n"
    rows = "".join(f"{i / 100!r},a,{i}\n{i / 100!r},b,{i}\n" for i in range(151))
    thin = golden.thin_csv(header + rows, keep=21)
    times = sorted({float(r.split(",")[0]) for r in thin.splitlines()[1:]})
    assert times[0] == 0.0 and times[-1] == 1.5 and len(times) <= 21
    assert len(thin.splitlines()) == 1 + 2 * len(times)  # every entity of a kept time


SCENE = """vrsim: 1
name: drop
duration: 0.5
frame_rate: 20
dt: 0.01
bodies: [{name: ball, mass: 1, position: [0, 1, 0]}]
"""


def test_regenerate_check_and_the_missing_golden_message(tmp_path, capsys):
    scenarios, gold = tmp_path / "scenarios", tmp_path / "golden"
    scenarios.mkdir()
    (scenarios / "drop.yaml").write_text(SCENE)
    assert golden.main([], scenarios, gold) == 1
    assert f"drop: no golden file drop.csv.gz; create it with `{golden.REGENERATE}`" \
        in capsys.readouterr().out
    assert golden.main(["--update"], scenarios, gold) == 0
    first = (gold / "drop.csv.gz").read_bytes()
    assert golden.main([], scenarios, gold) == 0
    assert golden.main(["--update"], scenarios, gold) == 0
    assert "drop: golden unchanged" in capsys.readouterr().out
    assert (gold / "drop.csv.gz").read_bytes() == first  # the diff of a rerun is empty
    # a change in the physics: the check fails, an update reports the change and rewrites
    (scenarios / "drop.yaml").write_text(SCENE.replace("position: [0, 1, 0]",
                                                       "position: [0, 1.001, 0]"))
    assert golden.main([], scenarios, gold) == 1
    assert golden.main(["--update"], scenarios, gold) == 0
    out = capsys.readouterr().out
    assert "largest position error: 0.001 m" in out and "state sha256 " in out
    assert golden.main([], scenarios, gold) == 0
    # a removed scenario takes its golden and pins with it
    shutil.copy(scenarios / "drop.yaml", scenarios / "other.yaml")
    golden.main(["--update"], scenarios, gold)
    (scenarios / "other.yaml").unlink()
    golden.main(["--update"], scenarios, gold)
    assert sorted(p.name for p in gold.iterdir()) == ["drop.csv.gz", "hashes.json"]
    assert golden.main(["nonesuch"], scenarios, gold) == 2
