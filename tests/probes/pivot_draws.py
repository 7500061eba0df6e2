# Usage: python tests/probes/pivot_draws.py SEED... (from the repo root): runs tests/test_stepped_pivot.py
# on any draws and prints ok or the first gain.
import sys, math, numpy as np
sys.path.insert(0, 'tests')
import test_stepped_pivot as T
from conftest import simulate
import conftest
res = []
orig = T.simulate
def wrap(src):
    out = orig(src)
    wrap.last = out
    return out
T.simulate = wrap
for seed in [int(a) for a in sys.argv[1:]] or range(16):
    try:
        T.test_a_box_falling_over_an_edge_never_gains_energy(seed)
        print(seed, "ok")
    except AssertionError as e:
        print(seed, "FAIL", str(e).split("\n")[0][:150])
