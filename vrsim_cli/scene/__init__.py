"""Layer 1, scene: YAML → a validated spec that remembers the line and column of every
value (`spec`), checked against the JSON Schema shipped beside it (`scene.schema.json`)
and by semantic checks the schema cannot express (`animation`, `rigid`)."""
