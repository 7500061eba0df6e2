"""Loop stage 2.1, dynamic motion (slide 5.3): `motion.step` advances every body by one
step; `integrators` (translation), `rigid` (rotation, torques, springs) and `free_body`
(the exact torque-free flow) are its parts."""
