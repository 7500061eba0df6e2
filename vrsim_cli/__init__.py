"""vrsim: a command-line scenario runner for real-time animation and simulation in VR.

The package follows the loop of lecture chapter 5 (slide 5.0): read sensors, simulate,
update the scene graph and render. Importing it is cheap: numpy and the heavy optional
libraries (trimesh, fcl, OpenGL, matplotlib) are imported by the stage that needs them.
"""

__version__ = "0.1.0"
