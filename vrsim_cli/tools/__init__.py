"""Layer 7, tools built on runs and their outputs: `bench` (work-precision and throughput
against MuJoCo and PyBullet), `compare` (trajectory regression), `trajectory` (reading
outputs back) and `walk_table` (slide 5.1's table from a run)."""
