"""Training: train step, optimizer, schedules, loop, checkpoints, run directories, devices."""
