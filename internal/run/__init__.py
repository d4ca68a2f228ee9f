"""Run infrastructure: run directories and their lock, checkpoints, devices and processes, memory errors."""
