"""Real datasets as worlds of the synthetic world's layout (ushape.data.layout).

shapenet, shapenet_world      ShapeNetCore v1/v2 models, splits and preprocessing into a world
shapenet_rendering            the 3D-R2N2 renders (ShapeNetRendering) and their cameras
pix3d                         Pix3D's photos, masks and models as an evaluation world
mesh_sdf, mesh_signs          SDF samples of real (non-watertight) meshes: distances and signs
reach_grid                    what a path from outside reaches: surface voxels and an exterior flood fill
mesh_orientation              outward-oriented faces and their winding number, the signs' second opinion
sign_cases, voxel_check       known-answer meshes and official voxels to check the signs against
mesh_sdf_bench                `ushape sign-bench`: those checks and timings as tables
"""
