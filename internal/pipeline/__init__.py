"""The pipeline: the training loop that runs the step, checkpoints, evaluation and learning curves over a run."""
