"""Evaluation: the paper's metrics, protocols, tables and plots (what `python eval.py` runs).

    uncertainty           latent / SDF-space ES and NLL, surface split, SDF propagation with clamping
    views                 deterministic corrupted views and cached encodings
    code_metrics          code -> SDF grid -> mesh and voxels -> metrics, cached by the code's hash
    protocols             single view, multi view (instances of 10 views), corrupted views -> records
    uncertainty_protocol  Table S1 rows and calibration curves with the equal-variance baseline
    settings              the size preset (conf/protocol/quick, paper) and the result files' names
    plugin, plugins/      the protocol interface and the protocols, each from conf/protocol/plugins/<name>.yaml
    context               one encoder's evaluation: encodings by crop, shared records, other protocols' outputs
    methods               reconstruction methods: each scored as rows of its own in every table
    encoders, runner, sources   which runs and their encoders, and every protocol for each of them
    tables, plots, report, showcase   the paper's tables, figures, result files, meshes with uncertainty
    command, gather       eval.py's config -> evaluation; one table from a sweep's evaluation rows

Import the module you need; this package imports nothing itself, so importing one module does not
pull in matplotlib. The scoring maths it uses (Pix3D's IoU, Chamfer and EMD; proper scores;
calibration) lives in ushape.metrics.
"""
