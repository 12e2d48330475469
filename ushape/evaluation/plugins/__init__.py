"""The paper's evaluation protocols (and ours) as plug-ins, one module each, built from
conf/protocol/plugins/<name>.yaml.

single_view   Table 1: every clean test view on its own (and its reference rows)
multi_view    Table 3: instances of group_size views fused by every rule
corrupted     Tables 4-5: single views and instances with every view cropped
uncertainty   Tables S1 and U: latent / SDF-space scores, whether the variance tracks the error
locality      Table L: where on the shape the uncertainty sits
depth         Table D: depth-std calibration
active        Table A: next-best-view (asked for by name)
"""
