#!/usr/bin/env bash
# A virtualenv of its own with LeRobot's dataset loader, for tests/dataset/test_lerobot_export.py,
# which loads our LeRobot export with LeRobot's own LeRobotDataset.
# Usage: scripts/lerobot-venv.sh [PYTHON]   (PYTHON: a Python 3.11, default python3.11)
# Idempotent: the venv is cached under ${XDG_CACHE_HOME:-~/.cache}/crowdteleop/ and reused once
# its stamp file exists (written last, so a half-made venv is rebuilt); the last line printed is
# the venv's python.
set -euo pipefail
python="${1:-python3.11}"

# lerobot 0.4.4 is the newest release for Python 3.11; it declares torch<2.11 and
# torchvision<0.26. torch 2.9.1 + torchvision 0.24.1 (PyPI's CUDA build, ~7 GB, runs on the CPU):
# LeRobot's "pyav" video backend decodes through torchvision.io.VideoReader, which torchvision
# 0.28 dropped, so the torch 2.13/2.14 wheels on this machine's disk cannot decode its videos,
# and PyPI's torchvision 0.24/0.25 does not import beside them (operator torchvision::nms does not
# exist). lerobot itself goes in without its dependencies (robot drivers, wandb, rerun, opencv,
# torchcodec, which needs system FFmpeg): below is what `lerobot.datasets.lerobot_dataset`
# imports, pinned to what resolved within lerobot 0.4.4's bounds when this was written (so CI
# gets the venv that was tested; a new pin makes a new venv).
lerobot="lerobot==0.4.4"
requirements=(
  "torch==2.9.1"
  "torchvision==0.24.1"
  "datasets==4.8.5"
  "huggingface-hub==0.35.3"
  "accelerate==1.15.0"
  "av==15.1.0"
  "packaging==25.0"
  "numpy==2.4.6"
  "pandas==3.1.1"
  "pyarrow==26.0.1"
)

python_version=$("$python" -c 'import sys; print(sys.version_info[:2])')
key=$(printf '%s\n' "$lerobot" "${requirements[@]}" "$python_version" | sha256sum | cut -c1-12)
cache="${XDG_CACHE_HOME:-$HOME/.cache}/crowdteleop"
venv="$cache/lerobot-venv-0.4.4-$key"
stamp="$venv/.complete"
mkdir -p "$cache"

# One builder at a time (parallel test runs share the cache).
exec 9>"$venv.lock"
flock 9

if [ ! -f "$stamp" ]; then
  echo "Creating $venv (lerobot 0.4.4, torch 2.9.1: a ~7 GB download the first time)"
  rm -rf "$venv"
  "$python" -m venv "$venv"
  pip=("$venv/bin/python" -m pip --disable-pip-version-check --no-input)
  "${pip[@]}" install --progress-bar off "${requirements[@]}"
  "${pip[@]}" install --progress-bar off --no-deps "$lerobot"
  "$venv/bin/python" -c \
    "import lerobot.datasets.lerobot_dataset, torchvision.io; torchvision.io.VideoReader"
  printf '%s\n' "$lerobot" "${requirements[@]}" >"$stamp"
fi
echo "$venv/bin/python"
