"""scenes: small test cases as data or generators (the self-illumination corner, a model
with markers, ...). Each module builds its scene from a few parameters, deterministically."""
