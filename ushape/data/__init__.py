"""Data: DeepSDF SDF samples, ShapeNetRendering-style cameras and renders, the cached synthetic world.

Modules: sampling (SDF samples), cameras (R2N2 protocol), shading + rendering (ray casting),
layout (cache folder names, WorldIndex), integrity (cache file checks), shape_artifacts (one
shape's files), world (SyntheticWorld), preview (gallery script).
"""
