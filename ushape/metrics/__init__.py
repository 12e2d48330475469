"""The pure scoring maths, shared by training, recalibration and evaluation (torch, numpy, scipy).

    reconstruction   DeepSDF's Chamfer distance, volumetric IoU, inside tests of meshes and SDFs
    pix3d            Pix3D's IoU (32^3 voxels), Chamfer and EMD (1024 points), per-shape unit boxes
    scores           univariate Gaussian NLL and Energy Score (CRPS) in closed form
    calibration      calibration curves, calibration error and their plot (matplotlib imported when plotting)

Keeping them below the stages lets each import them without importing the others.
"""
