"""Meshes from SDFs: marching cubes (dense and coarse-to-fine) in the normalised frame."""
