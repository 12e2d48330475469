"""Evaluation: the paper's metrics, protocols, tables and plots (what `python eval.py` runs).

    metrics               Pix3D's IoU (32^3 voxels), Chamfer and EMD (1024 points), per-shape unit boxes
    uncertainty           latent / SDF-space ES and NLL, surface split, SDF propagation with clamping
    views                 deterministic corrupted views and cached encodings
    reconstruct           code -> SDF grid -> mesh and voxels -> metrics, cached by the code's hash
    protocols             single view, multi view (instances of 10 views), corrupted views -> records
    uncertainty_protocol  Table S1 rows and calibration curves with the equal-variance baseline
    runner, sources       which runs, and every protocol for each of their encoders
    tables, plots, report, showcase   the paper's tables, figures, result files, meshes with uncertainty
    command, gather       eval.py's config -> evaluation; one table from a sweep's evaluation rows

Import the module you need; this package imports nothing itself, so `import ushape.evaluation.metrics`
does not pull in matplotlib. Calibration curves and proper scores live in ushape.scoring.
"""
