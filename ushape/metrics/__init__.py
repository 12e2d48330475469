"""Reconstruction metrics: DeepSDF's Chamfer distance and volumetric IoU."""
