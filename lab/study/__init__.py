"""Studies: grids of runs from a TOML file, run on this machine or a Ray cluster, gathered into tables and plots.

runner.py is the command (`python -m lab.study STUDY.toml`); spec.py reads study files; dispatch.py, claim.py and
ray_executor.py run cells (claimed, so runners can share a folder); stats.py, time_budgets.py, plots.py, export.py,
reuse.py and estimate.py turn finished cells into numbers, pictures, exports and estimates (cells_file.py: an export's
cells in one file, and the conversion of the earlier layout); executor_overhead.py times the executors.
"""
