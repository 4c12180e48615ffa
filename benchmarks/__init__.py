"""Speed benchmarks of safe-nav, outside the runtime packages.

Each benchmark prints ratios against a reference measured in the same run (CVXPY, the
unfiltered environment, plain training), because these machines are shared and noisy.
Run them with ``python -m benchmarks`` (the same options as ``safe-nav bench``).
"""
