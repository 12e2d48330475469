#!/usr/bin/env bash
# The shipped real-shape models, reproduced from the 3D-R2N2 voxels (docs/pretrained.md):
#
#   nohup bash notebooks/train_pretrained.sh chairs tables > outputs/pretrained_train.log 2>&1 &
#
# Per category, one job at a time on all cores (two 1-thread jobs side by side ran 2.0-2.2 steps/s each,
# one 2-thread job ~5): the r2n2 world (1,000 / 100 / 100 shapes, ~5 min), stage 1 (200 epochs of the
# 4 x 256 decoder, ~45 min at 2 threads on an AMD EPYC), then stage 2 (the frozen-feature ES heads, and the
# L2 heads of the FroDO* comparison on the same cached features, trained last), the ES run's temperature,
# shared-error fusion, refinement calibration and camera-azimuth head, and the export into
# ushape/pretrained/<category>/. Stage 2's runs are outputs/pretrained_runs/<decoder folder>-<settings>/encoder_{es,l2}.
# Every step resumes where it stopped: rerun the same command. A stage-1 folder committed under
# ushape/pretrained/<category>/decoder/ or notebooks/stage1/<its folder name>/ (decoder, codes, DONE,
# identity.json; or only the decoder, the training codes and FITTED, whose held-out codes are then
# latent-optimised) is copied into outputs/decoders/ first, so a fresh machine goes on with stage 2 instead of
# training stage 1 again (only where that folder's identity is this config's: the same decoder, data and
# recipe).
#
# Another decoder: DECODER_OVERRIDES adds Hydra overrides to every step, e.g. the 4 x 512 of
# notebooks/train_wide_stage1.sh, whose stage 1 this then finds finished and goes on from:
#
#   DECODER_OVERRIDES="decoder.hidden_dims=[512,512,512,512] stage1.module.lr_net=1.0e-3" \
#     nohup bash notebooks/train_pretrained.sh chairs > outputs/pretrained_train.log 2>&1 &
#
# EXPORT_ROOT=outputs/candidates exports the model there instead of into the package (ushape/pretrained/), so
# that a candidate is measured (`--model` takes its folder's path) before it replaces the shipped one.
set -euo pipefail
cd "$(dirname "$0")/.."
VOXELS=${VOXELS:-$(realpath ../shared/data/ShapeNetVox32)}
THREADS=${THREADS:-$(nproc)}
# fp32 throughout, as the shipped models were trained (bf16 "auto" would train differently on an AMX CPU,
# and the committed stage 1 would be restored into a folder named for a bf16 decoder).
COMMON=(experiment=r2n2_cpu_2h "data.voxels_root=$VOXELS" data.n_val=100 data.n_test=100 data.num_workers=0
  stage1.latent_optim.samples_per_iter=1000 stage1.module.bf16=false stage1.latent_optim.bf16=false
  stage2.module.bf16=false)
read -r -a EXTRA <<< "${DECODER_OVERRIDES:-}"
COMMON+=("${EXTRA[@]}")

decoder_dir() {  # the stage-1 folder train.py uses for this category's config
  .venv/bin/python notebooks/decoder_dir.py "category=$1" "${COMMON[@]}"
}

categories=("$@")
[[ ${#categories[@]} -gt 0 ]] || categories=(chairs tables)
for category in "${categories[@]}"; do
  folder=$(decoder_dir "$category")
  # a finished stage 1 kept in the tree: the shipped model's, or another decoder's under notebooks/stage1/
  for committed in "ushape/pretrained/$category/decoder" "notebooks/stage1/${folder##*/}"; do
    [[ (-f $committed/DONE || -f $committed/FITTED) && -f $committed/identity.json && ! -f $folder/DONE ]] || continue
    committed_hash=$(.venv/bin/python -c "import json, sys
from ushape.training.decoder_store import identity_hash as h; print(h(json.load(open(sys.argv[1]))))" \
      "$committed/identity.json")
    [[ ${folder##*-} == "$committed_hash" ]] || continue
    mkdir -p "$folder"
    for file in decoder.pt codes_train.pt codes_val.pt codes_test.pt FITTED DONE; do
      if [[ -f $committed/$file ]]; then cp "$committed/$file" "$folder"/; fi
    done
    echo "stage 1 of $category restored from $committed into $folder (no epoch runs again)"
  done
  OMP_NUM_THREADS=$THREADS nice -n 5 .venv/bin/python train.py "${COMMON[@]}" stage=decoder loss=es category="$category"
  # Stage 2 writes into folders named by the decoder and these exact settings, so a rerun resumes the heads
  # from their last.ckpt (a finished one, with its run.json, is not trained again).
  runs="outputs/pretrained_runs/${folder##*/}-$(printf '%s\n' "${COMMON[@]}" | sha1sum | cut -c1-8)"
  encoder() {  # loss
    [[ -f $runs/encoder_$1/run.json ]] && return
    OMP_NUM_THREADS=$THREADS nice -n 5 .venv/bin/python train.py "${COMMON[@]}" stage=encoder loss="$1" \
      category="$category" "hydra.run.dir=$runs/encoder_$1"
  }
  encoder es
  run=$runs/encoder_es
  [[ -f $run/checkpoints/temperature.json ]] || .venv/bin/python reconstruct.py --fit-temperature --run "$run"
  [[ -f $run/checkpoints/refinement_calibration.json ]] ||
    .venv/bin/python reconstruct.py --fit-refinement masks --fit-shapes 20 --run "$run"
  [[ -f $run/checkpoints/viewpoint.pt ]] || .venv/bin/python reconstruct.py --fit-viewpoint --run "$run"
  .venv/bin/python -c "import sys; from ushape.reconstruction.pretrained import export_pretrained as e
print(e(sys.argv[1], sys.argv[2], sys.argv[3], category=sys.argv[2]))" "$run" "$category" "${EXPORT_ROOT:-ushape/pretrained}"
  encoder l2  # FroDO*'s heads on the same cached features, for the comparison rows (not part of the export)
done
