"""Layer 0, maths: pure functions that know no scene — quaternions and rotations
(`spatial`, `rotation`), exact signed distances and ray casts of analytic shapes
(`geometry`), triangle meshes and their proxies (`meshes`, `queries`), the perspective
camera (`camera`), the Dormand–Prince solver (`adaptive`) and slide 5.4.2's impulse law
(`impulse`)."""
