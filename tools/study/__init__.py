"""Studies: grids of runs from a TOML file, run on this machine or a Ray cluster, gathered into tables and plots.

runner.py is the command (`python -m tools.study STUDY.toml`); spec.py reads study files; schedule.py, claim.py and
ray_executor.py run cells (claimed, so runners can share a folder); stats.py, budget.py, plots.py, export.py,
reuse.py and cost.py turn finished cells into numbers, pictures, exports and estimates (cells_file.py: an export's
cells in one file, and the conversion of the earlier layout); overhead.py times the executors.
"""
