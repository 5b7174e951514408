#!/usr/bin/env bash
# Creates or refreshes the project's virtualenv. Usage: scripts/setup-venv.sh PYTHON VENV
set -euo pipefail
python="${1:-python3}"
venv="${2:-.venv}"

# mujoco 4 ships as split packages that own the same files: a venv that ever held it cannot be
# downgraded in place (platform-notes.md), so start over.
if [ -x "$venv/bin/python" ] && "$venv/bin/python" - <<'PY' 2>/dev/null
import importlib.metadata as md, sys
sys.exit(0 if md.version("mujoco").split(".")[0] >= "4" else 1)
PY
then
  echo "Recreating $venv (it holds mujoco 4, which robosuite 1.5.2 cannot use)"
  rm -rf "$venv"
fi

[ -x "$venv/bin/python" ] || "$python" -m venv "$venv"
"$venv/bin/python" -m pip install --quiet --upgrade pip
# torch is not needed yet; when it is, pin torch==2.13.0 (the CPU build on this machine's disk).
"$venv/bin/python" -m pip install --quiet -e ".[dev]"
# robomimic's dataset loader (the dataset tests load our HDF5 with it). Without its declared
# dependencies: they pin torchvision (fails to import beside torch 2.13) and egl_probe (needs
# cmake); what its loader imports (torch, h5py, tqdm, termcolor) is in pyproject's dev list.
"$venv/bin/python" -m pip install --quiet --no-deps "robomimic==0.3.0"

# robosuite warns on every import until a private macro file exists; create it once, quietly.
robosuite_dir=$("$venv/bin/python" -c "import importlib.util as u; print(u.find_spec('robosuite').submodule_search_locations[0])")
if [ ! -f "$robosuite_dir/macros_private.py" ]; then
  sed -e 's/^CONSOLE_LOGGING_LEVEL = .*/CONSOLE_LOGGING_LEVEL = "ERROR"/' \
      "$robosuite_dir/macros.py" > "$robosuite_dir/macros_private.py"
fi
