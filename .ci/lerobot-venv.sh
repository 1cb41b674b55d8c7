#!/usr/bin/env bash
# Build a side virtual environment with lerobot 0.4.4 in it, to check that lerobot itself loads the
# LeRobot v3 datasets bench writes (tests/test_lerobot_interop.py), and to train and serve lerobot policies
# that bench evaluates over the remote-policy protocol (baselines/lerobot_adapter.py,
# tests/test_lerobot_remote.py). It is never bench's own environment:
# lerobot brings pandas, and its pins (torch<2.11, torchvision<0.26) would pull a CUDA torch of several GB.
# So: torch 2.13.0 CPU first, lerobot without its dependencies, then the part of its dependency list that
# dataset loading and training import (pyserial and diffusers: lerobot's training script imports every policy
# and robot module), within lerobot's own version ranges where the registry has them, plus websockets and
# msgpack for the adapter's server (bench's own wire code, imported from this checkout), and lerobot's simulated
# envs (gym-aloha, gym-pusht) at the versions bench pins, for lerobot-eval (tests/test_lerobot_parity.py).
#
#   bash .ci/lerobot-venv.sh [DIR]          # default DIR: .lerobot-venv (git-ignored)
#   BENCH_LEROBOT_PYTHON=DIR/bin/python pytest tests/test_lerobot_interop.py
#
# Video features: lerobot decodes them with torchcodec, which loads FFmpeg's shared libraries from the system.
# The torchcodec built against torch 2.13 is 0.12.0 (0.10, the newest inside lerobot's range <0.11, fails to
# load: its compiled core was linked against an older torch); the FFmpeg it finds is Debian 12's (5.1), installed
# with apt when missing (these machines run as root).
#
# One adjustment, stated: the torchvision wheel that matches torch 2.13.0 (0.28.0) links its compiled ops
# against CUDA libraries the CPU torch lacks, so `import torchvision` fails while registering fake kernels
# for nms/roi_align. The script makes those two registration modules load only when the compiled ops
# loaded. lerobot's dataset code uses torchvision's pure-Python transforms only, never these ops.
set -euo pipefail
cd "$(dirname "$0")/.."
DIR="${1:-.lerobot-venv}"
python3 -m venv "$DIR"
PY="$DIR/bin/python"
"$PY" -m pip install -q torch==2.13.0
"$PY" -m pip install -q --no-deps lerobot==0.4.4 torchvision==0.28.0
"$PY" -m pip install -q "datasets>=4,<5" "huggingface-hub>=0.34.2,<0.36" "accelerate>=1.10,<2" "av>=15,<16" \
    "deepdiff>=7,<9" "packaging>=24.2,<26" "draccus==0.10.0" "jsonlines>=4,<5" "einops>=0.8,<0.9" \
    "termcolor>=2.4,<4" "gymnasium>=1.1,<2" "imageio>=2.34,<3" "numpy<2" "pyarrow<26" pillow \
    "pyserial>=3.5,<4" "diffusers>=0.27.2,<0.36" "websockets>=15,<18" "msgpack>=1.0.5"
# lerobot's simulated envs, at bench's pins (pyproject's lerobot-sims extra: the same physics on both sides, so
# lerobot-eval and bench run the same episodes; tests/test_lerobot_parity.py)
"$PY" -m pip install -q "mujoco==3.3.0" "gym-aloha==0.1.5" "dm-control==1.0.28" "gym-pusht==0.1.8" "numpy<2"
"$PY" -m pip install -q --no-deps torchcodec==0.12.0
FFMPEG_LIBS="libavutil57 libavcodec59 libavformat59 libavdevice59 libavfilter8 libswscale6 libswresample4"
if ! ldconfig -p | grep -q 'libavdevice\.so\.59'; then
  export DEBIAN_FRONTEND=noninteractive
  apt-get install -y -q --no-install-recommends $FFMPEG_LIBS >/dev/null \
    || { apt-get update -q >/dev/null && apt-get install -y -q --no-install-recommends $FFMPEG_LIBS >/dev/null; }
fi
"$PY" - <<'PYEOF'
import importlib.util, pathlib
init = pathlib.Path(importlib.util.find_spec("torchvision").origin)
s = init.read_text()
old = "    _autograd_registrations,\n    _meta_registrations,\n"
if old in s:
    s = s.replace(old, "", 1).replace(
        ")  # usort:skip\n",
        ")  # usort:skip\nif extension._has_ops():\n    from torchvision import _autograd_registrations, _meta_registrations\n", 1)
    init.write_text(s)
PYEOF
HF_HUB_OFFLINE=1 "$PY" -c "from lerobot.datasets.lerobot_dataset import LeRobotDataset; from torchcodec.decoders import VideoDecoder; import lerobot.scripts.lerobot_train, lerobot.scripts.lerobot_eval, websockets, msgpack, gym_aloha, gym_pusht; import lerobot; print('lerobot', lerobot.__version__, 'ready in', '$DIR')"
