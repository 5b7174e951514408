#!/usr/bin/env bash
# Installs the Debian packages crowdteleop needs, and only those that are missing, so a second
# run costs a few dpkg queries. Usage: scripts/system-deps.sh [run|test]
set -euo pipefail

profile="${1:-run}"
packages=(
  python3-venv   # the venv module on a stock Debian python3
  libosmesa6     # MuJoCo offscreen rendering without a GPU (MUJOCO_GL=osmesa)
  libegl1        # MuJoCo offscreen rendering through EGL (GPU or Mesa llvmpipe)
  libgl1
  libglib2.0-0
)
if [ "$profile" = "test" ]; then
  packages+=(
    postgresql   # the coordination server's database tests run against a real PostgreSQL
    chromium     # the web pages' end-to-end tests (Playwright drives /usr/bin/chromium)
    coturn       # TURN: a session relayed through a real TURN server (relay-only ICE)
    iperf3       # the link emulator's rate and loss, measured by a tool that is not ours
    haproxy      # a real load balancer in front of two coordinator replicas
    caddy        # the reverse proxy of docs/deploy.md, which its test runs as the guide says
  )
  # The pages' JS unit tests run on node's own test runner; any node >= 18 will do.
  command -v node >/dev/null || packages+=(nodejs)
fi

# The database tests need PostgreSQL listening on 127.0.0.1:5432 (trust auth, database test).
start_postgres() {
  [ "$profile" = "test" ] || return 0
  command -v pg_isready >/dev/null || return 0
  pg_isready -q -h 127.0.0.1 -p 5432 && return 0
  local version
  version=$(ls /etc/postgresql 2>/dev/null | sort -V | tail -n 1)
  [ -n "$version" ] || { echo "warning: PostgreSQL is installed but has no cluster" >&2; return 0; }
  echo "Starting PostgreSQL $version"
  pg_ctlcluster --skip-systemctl-redirect "$version" main start || true
  for _ in $(seq 1 30); do pg_isready -q -h 127.0.0.1 -p 5432 && return 0; sleep 0.5; done
  echo "warning: PostgreSQL did not come up on 127.0.0.1:5432" >&2
}

missing=()
for pkg in "${packages[@]}"; do
  # python3-venv only matters for the Debian python3; a pyenv/conda python brings its own venv.
  if [ "$pkg" = "python3-venv" ] && python3 -c "import ensurepip, venv" 2>/dev/null; then
    continue
  fi
  dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed" || missing+=("$pkg")
done

if [ ${#missing[@]} -eq 0 ]; then
  start_postgres
  exit 0
fi

echo "Installing Debian packages: ${missing[*]}"
sudo=""
if [ "$(id -u)" -ne 0 ]; then
  command -v sudo >/dev/null || { echo "error: need root (or sudo) to install: ${missing[*]}" >&2; exit 1; }
  sudo="sudo"
fi
export DEBIAN_FRONTEND=noninteractive
$sudo apt-get update -qq
$sudo apt-get install -y -qq --no-install-recommends "${missing[@]}"
start_postgres
