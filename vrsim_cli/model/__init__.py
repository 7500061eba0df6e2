"""Layer 2, model: spec → a frozen `Model` (structure-of-arrays numpy, MuJoCo's mjModel)
and the one mutable `State` (mjData). `model` compiles the whole; its parts are compiled
by `observer`, `rigid` (with `mass_properties`), `animation` (with `keyframes`),
`frames`, `collision` and `response`; `state` makes and hashes states."""
