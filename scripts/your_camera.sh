#!/usr/bin/env bash
# Your camera, end to end (README, "Your camera, end to end", steps 3-6), as one command:
# calibrate the ELD model, close the loop, train the denoiser on your clean frames with the
# loop's profile, and denoise your low-light shots into DNG files a raw developer opens.
#
#   scripts/your_camera.sh FRAMES CLEAN SHOTS OUT [fit.py options ...]
#
# FRAMES  a frame manifest (path, kind, iso, exposure_s) or a folder of bias/dark/flat raw files
# CLEAN   clean frames: CLEAN/train/ and CLEAN/val/, or a manifest.csv with a split column
# SHOTS   the real noisy raw shots to denoise
# OUT     new or rawaug's own folder: profile.yaml, calibration/ (calibrate's report),
#         loop_profile.yaml, loop/ (the loop's report), run/ (checkpoints, val_results.csv,
#         TensorBoard), denoised/ (.npy and .dng)
# Environment: CAMERA (the name results carry, default: OUT's name), RATIO (the shots'
# amplification, the low-light ratio the network undoes; default 100), LOOP_OPTIONS (more
# options of rawaug loop, e.g. "--n-synth 16"). fit.py options (e.g. --trainer.max_epochs 64)
# go to training and prediction alike.
set -euo pipefail

if [ "$#" -lt 4 ]; then
    sed -n '2,17p' "$0" | sed 's/^# \{0,1\}//' >&2
    exit 2
fi
frames=$1 clean=$2 shots=$3 out=$4
shift 4
camera=${CAMERA:-$(basename "$out")}
ratio=${RATIO:-100}
read -r -a loop_options <<< "${LOOP_OPTIONS:-}"
app="$(cd "$(dirname "$0")/.." && pwd)/lightning_app/fit.py"
config="$(dirname "$app")/../configs/quickstart.yaml"
mkdir -p "$out"

echo "== 1/4 calibrate: $frames"
rawaug calibrate "$frames" --camera "$camera" --out "$out/profile.yaml" --report "$out/calibration"

echo "== 2/4 close the loop"
rawaug loop "$frames" --camera "$camera" --out "$out/loop_profile.yaml" --report "$out/loop" ${loop_options[@]+"${loop_options[@]}"}

run=("--config" "$config" "--model.profile" "$out/loop_profile.yaml"
     "--trainer.default_root_dir" "$out/run" "--trainer.logger.init_args.save_dir" "$out/run"
     "--model.results_dir" "$out/run/results")
echo "== 3/4 train on $clean with the loop's profile"
python "$app" fit "${run[@]}" \
    --data.init_args.train.init_args.root "$clean" --data.init_args.train.init_args.camera "$camera" \
    --data.init_args.val.init_args.root "$clean" --data.init_args.val.init_args.camera "$camera" "$@"

ckpt=$(ls -t "$out"/run/version_*/checkpoints/last.ckpt | head -n 1)
echo "== 4/4 denoise $shots with $ckpt"
python "$app" predict "${run[@]}" --ckpt_path "$ckpt" \
    --data.init_args.predict=rawaug.train.NoisyFolder --data.init_args.predict.root "$shots" \
    --data.init_args.predict.ratio "$ratio" \
    --trainer.callbacks+=rawaug.train.DenoisedWriter --trainer.callbacks.output_dir "$out/denoised" \
    --trainer.callbacks.format both "$@"
echo "done: $out/loop/report.md, $out/run/results/, $out/denoised/"
