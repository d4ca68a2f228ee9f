"""The GPU ledger: the paper-length runs that lent GPU windows move forward (ledger.toml), what a window trains next
and hands back (window.py), what came back committed into results/gpu/ledger/ (commit.py); `python -m lab.ledger`
(__main__.py)."""
