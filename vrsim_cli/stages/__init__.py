"""Layer 4, the stages of slide 5.0's loop, one module or subpackage each: `sensors` (1),
`dynamics` (2.1), `navigation` (2.2), `collision` (2.3: detection and response) and
`scenegraph` (3; rendering is `vrsim_cli.render`). Stages never import each other; the
loop (`vrsim_cli.loop`) composes them and passes what one needs of another."""
