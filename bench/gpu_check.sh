#!/usr/bin/env bash
# `bash bench/gpu_check.sh`: the name of `bash lab/gpu_check.sh` before it moved to the lab wing; runs it for a turn, saying so.
echo "note: bench/gpu_check.sh is now lab/gpu_check.sh; the old name goes in a later version" >&2
exec bash "$(dirname "${BASH_SOURCE[0]}")/../lab/gpu_check.sh" "$@"
