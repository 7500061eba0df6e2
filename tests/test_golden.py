"""Every scenario against its golden trajectory and its pinned state hash, through
`vrsim regress` (vrsim_cli/tools/regress.py; tests/golden.py says how to regenerate).

A scenario without a golden or a pin fails with the command that makes one; regenerating
is a deliberate act (`vrsim regress scenarios --golden tests/golden --update`,
docs/regression.md). The scenarios run twice, on a pool of two worker processes and in
this process: the same hashes and the same golden bytes from both are the reproducibility
the goldens rely on, and show that the executor does not change a bit.
"""

from __future__ import annotations

import pytest

import golden
from vrsim_cli.tools import regress
from vrsim_cli.tools.executors import LocalPool, Serial

NAMES = sorted(regress.scene_files(golden.SCENARIOS))


@pytest.fixture(scope="module")
def results():
    """(result on two worker processes, result in this process) of every scenario."""
    plan = regress.plan_regress(golden.SCENARIOS, golden.GOLDEN)
    out = []
    for executor in (LocalPool(2), Serial()):
        try:
            out.append(regress.run_regress(plan, executor,
                                           update_command=golden.REGENERATE))
        finally:
            executor.close()
    return out


def test_there_are_scenarios():
    assert NAMES, f"no scenarios in {golden.SCENARIOS}"


@pytest.mark.parametrize("name", NAMES)
def test_scenario_matches_its_golden(name, results):
    path = regress.golden_path(golden.GOLDEN, name)
    assert path.exists(), (f"scenario '{name}' has no golden trajectory {path}: "
                           f"run `{golden.REGENERATE}` and review the new file")
    case = results[0].cases[name]
    assert case.outcome.status == "ok", case.reasons
    assert case.outcome.ok, "\n".join(case.lines) + (
        f"\nIf this change in the numbers is intended, run `{golden.REGENERATE}` and "
        f"commit the goldens.")


@pytest.mark.parametrize("name", NAMES)
def test_two_runs_give_the_same_hash_and_the_same_bytes(name, results):
    pool, serial = (r.cases[name].outcome for r in results)
    assert pool.state_sha256 == serial.state_sha256
    assert pool.csv == serial.csv and pool.csv


@pytest.mark.parametrize("name", NAMES)
def test_state_hash_equals_the_pin_for_this_platform(name, results):
    pins = regress.plan_regress(golden.SCENARIOS, golden.GOLDEN, [name]).pins or {}
    platform = regress.platform_key()
    assert name in pins.get(platform, {}), (f"no pinned state hash for scenario '{name}' on "
                                            f"{platform}: run `{golden.REGENERATE}`")
    assert results[0].cases[name].outcome.state_sha256 == pins[platform][name], (
        f"'{name}' no longer reproduces its pinned final state bit for bit on {platform}; "
        f"if intended, run `{golden.REGENERATE}`")


def test_regress_passes_as_a_whole(results):
    """What CI would see: every scene passes (trajectory and pin), none errs."""
    assert results[0].ok, {n: c.reasons for n, c in results[0].cases.items() if c.reasons}


def test_no_golden_without_a_scenario():
    stale = sorted(p.name for p in golden.GOLDEN.glob("*.csv.gz")
                   if p.name[: -len(".csv.gz")] not in NAMES)
    assert not stale, f"goldens of removed scenarios: {stale}; run `{golden.REGENERATE}`"


def test_every_scene_tolerance_names_a_scenario_and_is_looser_than_the_default():
    """A tolerance for a scenario that does not exist is a typo that loosens nothing; a
    scene entry tighter than the default would be a mistake in the other direction."""
    tol = regress.load_tolerances(golden.GOLDEN / regress.TOLERANCES)
    assert tol.default.atol == 1e-9 and tol.default.angle_tol == 1e-9
    for name, scene_tol in tol.scenes.items():
        assert name in NAMES, f"tolerances.yaml names '{name}', which is no scenario"
        assert scene_tol.atol >= tol.default.atol
        assert scene_tol.angle_tol >= tol.default.angle_tol


def test_the_shim_runs_vrsim_regress(capsys):
    """`python tests/golden.py NAME` is `vrsim regress scenarios --golden tests/golden NAME`."""
    assert golden.command(["--update", "x"])[:4] == ["regress", str(golden.SCENARIOS),
                                                      "--golden", str(golden.GOLDEN)]
    assert golden.main(["projectile", "--jobs", "1"]) == 0
    assert "projectile: ok" in capsys.readouterr().out
    assert golden.main(["nonesuch"]) == 2
