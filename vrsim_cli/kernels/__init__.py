"""Layer 3, compiled kernels: the hot loops of the stages, compiled by numba.

Conventions (docs/architecture.md, "Writing a kernel"):
- a kernel is a plain function decorated with `jit.kernel`: numba's `njit` with an on-disk
  cache and without `fastmath` (no reassociation, no contraction into FMA), so a kernel
  gives the same bits on every run and on every x86-64 CPU;
- it takes contiguous float64 / int64 / bool arrays named as in the model and the state
  (`body_pos (n_body, 3) m`), writes its outputs into arrays it is given, and knows nothing
  of YAML, files or Python objects; small 3x3 and quaternion algebra is written out by
  components (`linalg.py`), never handed to BLAS;
- the stage module keeps a thin Python function that unpacks Model and State, calls the
  kernel and builds the next State, so the kernel can be tested alone against a plain
  reference, and the suite also passes with the JIT off (`NUMBA_DISABLE_JIT=1`).

Nothing here is imported by a scene that does not need it: `import vrsim_cli.kernels.x`
imports numba (about 0.3 s), so the stages import kernels inside the functions that call
them.
"""
