"""`vrsim bench`: `problems` (the problems, their truths, vrsim's runs), `peers` (MuJoCo
and PyBullet), `spheres` (problem 4 for every engine), `report` (registry, running,
Markdown, JSON, plots)."""
