#!/usr/bin/env bash
# What each doubling of the training shapes buys: stage 1 of the shipped recipe (experiment=r2n2_cpu_2h,
# 200 epochs of the 4 x 256 decoder, so steps grow with the shapes) on the first N training shapes by hash,
# then the ceiling on the same 100 val and 100 test shapes (their codes latent-optimised under each decoder),
# scored against R2N2's voxels by notebooks/r2n2_ceiling.py (docs/pretrained.md):
#
#   nohup bash notebooks/train_doubling.sh chairs 250 500 > outputs/doubling/chairs.log 2>&1 &
#
# A cap keeps the first ids by hash, so N=250 trains on a subset of N=500's shapes, and every N has the same
# val and test shapes (the world's samples and renders are seeded per shape). N=1000 is the shipped model's
# stage 1. Resumable: rerun the same command (world cache, decoder checkpoints, finished ceilings kept).
set -euo pipefail
cd "$(dirname "$0")/.."
VOXELS=${VOXELS:-$(realpath ../shared/data/ShapeNetVox32)}
THREADS=${THREADS:-$(nproc)}
category=${1:?usage: train_doubling.sh chairs|tables N [N ...]}
shift
COMMON=(experiment=r2n2_cpu_2h "data.voxels_root=$VOXELS" data.n_val=100 data.n_test=100 data.num_workers=0
  stage1.latent_optim.samples_per_iter=1000 stage1.module.bf16=false stage1.latent_optim.bf16=false
  "category=$category")
mkdir -p outputs/doubling
for n in "$@"; do
  out=outputs/doubling/${category}_$n.json
  [[ -f $out ]] && { echo "$out exists"; continue; }
  OMP_NUM_THREADS=$THREADS nice -n 5 .venv/bin/python train.py "${COMMON[@]}" "data.n_train=$n" stage=decoder
  folder=$(.venv/bin/python notebooks/decoder_dir.py "${COMMON[@]}" "data.n_train=$n")
  OMP_NUM_THREADS=$THREADS .venv/bin/python notebooks/r2n2_ceiling.py "$folder" --split test --shapes 100 \
    --out "$out.tmp" && mv "$out.tmp" "$out"
done
