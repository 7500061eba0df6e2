"""Many stepped steps in one compiled call (`kernels.stepped.run_entry`, the loop's call
between two output samples) against the plain reference: the loop stepping the same
scene one `stages.collision.stepped.step` call at a time, as it did before. Every sample,
the final state, the contacts and their impulses, the energy guard's baseline and every
error (its message, body and time, and the last good state written) must be the same
bits."""

from __future__ import annotations

import numpy as np
import pytest

from test_stepped import STACK, _random_scene, closed_box
from vrsim_cli.errors import SimulationError

FIELDS = ("step", "t", "ode_step", "body_pos", "body_vel", "body_quat", "body_angvel",
          "rot_matrix", "rot_angmom", "rot_energy0", "contact_impulse")
CONTACT_FIELDS = ("body_a", "body_b", "point", "normal", "depth", "toi")


class _Samples:
    def __init__(self):
        self.states = []

    def write(self, state):
        self.states.append(state)


def _run(text, batched, monkeypatch):
    """(model, samples, final state or the SimulationError) of `text`, with the loop's
    many-step calls (batched) or one stepped step per loop step (the reference)."""
    from vrsim_cli.loop import run
    from vrsim_cli.model.model import compile_model
    from vrsim_cli.model.state import make_state
    from vrsim_cli.scene.spec import parse_scene
    from vrsim_cli.stages.collision import stepped as stage
    from vrsim_cli.stages.dynamics import motion as dynamics

    model = compile_model(parse_scene(text))
    with monkeypatch.context() as m:
        if not batched:
            m.setattr(stage, "batched", lambda model, dynamics: False)
        else:
            assert stage.batched(model, dynamics)
        rec = _Samples()
        try:
            end = run(model, make_state(model), rec).state
        except SimulationError as error:
            end = error
    return model, rec.states, end


def _same(a, b):
    for name in FIELDS:
        x, y = getattr(a, name), getattr(b, name)
        if x is None or y is None:
            assert x is None and y is None, name
        else:
            assert np.asarray(x).tobytes() == np.asarray(y).tobytes(), name
    if a.contacts is None or b.contacts is None:
        assert a.contacts is None and b.contacts is None
        return
    for name in CONTACT_FIELDS:
        assert getattr(a.contacts, name).tobytes() == getattr(b.contacts, name).tobytes(), name


def _compare(text, monkeypatch):
    _, want, want_end = _run(text, False, monkeypatch)
    _, got, got_end = _run(text, True, monkeypatch)
    assert len(got) == len(want) >= 2
    for a, b in zip(got, want):
        _same(a, b)
    if isinstance(want_end, SimulationError):
        assert isinstance(got_end, SimulationError)
        assert str(got_end) == str(want_end)
        assert (got_end.body, got_end.t) == (want_end.body, want_end.t)
    else:
        _same(got_end, want_end)
    return want, want_end


@pytest.mark.parametrize("seed", range(3))
@pytest.mark.parametrize("rate", [100, 25])
def test_random_piles_give_the_bits_of_one_call_per_step(seed, rate, monkeypatch):
    """Random piles of spheres, boxes and capsules thrown at tilted planes (many impacts,
    resting contacts, warm starts across steps), sampled every step and every fourth."""
    text = _random_scene(np.random.default_rng(300 + seed), bodies=30, planes=3).replace(
        "duration: 0.05", "duration: 0.2").replace(
        "bodies:", f"output: {{rate: {rate}}}\nbodies:", 1)
    states, _ = _compare(text, monkeypatch)
    assert any(s.contacts is not None and len(s.contacts) for s in states)


@pytest.mark.parametrize("integrator", ["verlet", "rk4"])
def test_a_stack_gives_the_bits_of_one_call_per_step(integrator, monkeypatch):
    """scenarios/stack.yaml in stepped mode (shock propagation, position passes, the
    integrator's own step for bodies without contact impulses), 1 s, one sample a frame."""
    text = STACK.replace("integrator: verlet", f"integrator: {integrator}").replace(
        "duration: 10.0", "duration: 1.0")
    states, end = _compare(text, monkeypatch)
    assert len(end.contacts) >= 36  # nine box faces and the ground, four points each


def test_the_energy_guard_baseline_and_check_match(monkeypatch):
    """A force window that closes within a step (the guard's baseline is taken then) and
    the guard's check at every frame end afterwards: the same baseline bits."""
    text = closed_box(8, 1.0, 0.0, seed=9, duration=0.3).replace(
        "{name: s0, mass: 0.1,", "{name: s0, mass: 0.1, forces: [{force: [3, 0, 0], "
        "end: 0.0449}],", 1)
    states, end = _compare(text, monkeypatch)
    assert end.rot_energy0 is not None  # the baseline was taken in the run


def test_a_blow_up_raises_the_same_error_after_the_same_samples(monkeypatch):
    """A body pushed past the speed of light: the same error (message, body, time) and the
    same last good state written, whether the loop steps once per call or many."""
    text = closed_box(4, 0.5, 0.5, seed=3, duration=1.0).replace(
        "{name: s1, mass: 0.1,", "{name: s1, mass: 0.1, forces: [{force: [0, 1.0e11, 0], "
        "start: 0.1}],", 1)
    text = "\n".join(line for line in text.splitlines() if "name: lid" not in line) + "\n"
    _, end = _compare(text, monkeypatch)
    assert isinstance(end, SimulationError)
    assert "faster than light" in str(end) or "blew up" in str(end)


def test_the_many_steps_kernel_has_the_same_cache_key_in_every_process():
    """The run kernel is a closure over the step kernel; numba keys closures by a pickle
    that carries a random id per process, which would recompile it in every run. Its key
    (kernels/jit.py `_index_key`) is the same in two processes, and differs between two
    sets of pair kinds (whose step kernels differ)."""
    import subprocess
    import sys

    code = ("from vrsim_cli.kernels import stepped as ks, dynamics as kd\n"
            "from numba.core.registry import cpu_target\n"
            "kinds = [False] * len(ks.PAIR_KINDS)\n"
            "kinds[int(__import__('sys').argv[1])] = True\n"
            "d = ks.run_entry(tuple(kinds))\n"
            "print(d._cache._index_key((), cpu_target.target_context.codegen())[2])\n")

    def key(which):
        return subprocess.run([sys.executable, "-c", code, str(which)], check=True,
                              capture_output=True, text=True, timeout=300).stdout

    first = key(5)
    assert first and first == key(5)
    assert key(10) != first
