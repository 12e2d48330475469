"""Training orchestration: what `ushape train` / train.py runs (world, shared stage-1 decoder, stage 2, demo meshes)."""
