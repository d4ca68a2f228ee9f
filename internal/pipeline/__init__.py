"""The pipeline: the training loop that runs the step, checkpoints, evaluation and learning curves over a run.

A folder with one module because it is a stage of its own (tests/test_layering.py): the loop imports training,
run and evaluation, and no module of those stages may import it; the modules directly under internal/ are plain
records and the scripts' entry points, which this is neither.
"""
