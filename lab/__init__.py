"""The laboratory: the project's own instruments, run by its developers rather than by a user on a scene. The study
runner (study/), the GPU ledger and windows (ledger/, lease.sh, stages.sh, prepare_lease.py, gpu_check.sh,
gpu_report.py) and the project's reports (demo_seeds.py, depth_shape.py, camera_report.py). Of internal/ it imports
only the door to runs (internal/runs.py) and the small shared helpers (cli, atomic, progress, interrupt,
lock_holders); tests/test_layering.py checks it."""
