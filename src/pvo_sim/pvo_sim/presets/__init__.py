"""One module per world preset; each has ``build(spec, area, rng) -> WorldParts``."""
