"""Stage 1: the DeepSDF decoder f(x, z) -> SDF, trained as an auto-decoder."""
