"""Benchmarks: timings live here, never in the tests.

- ``scoreboard``: ``jaxdip bench`` (the dip-lqr loop against a NumPy loop, SciPy's RK45 and ode45's defaults,
  with accuracy against DOP853), the JSON and figure it writes;
- ``estimators``: throughput of the estimators on the linearised DIP, ``python -m jaxdip.bench.estimators``;
- ``noise``: the dip-lqr loop's sensor noise per period under each candidate generator (threefry, rbg,
  unsafe_rbg, Box-Muller, float32, one block per chunk) and the loop's periods/s with each,
  ``python -m jaxdip.bench.noise``;
- ``warm``: where each ``--quick`` run spends its time, cold and warm (import, trace, lower, compile or
  cache load, run, write), ``python -m jaxdip.bench.warm``;
- ``float32``: which experiments' Monte Carlo loops keep their statistics in float32 and their CPU-time ratio,
  ``python -m jaxdip.bench.float32`` (docs/performance.md, "float32, per loop");
- ``peers``: the batch filter/smoother/likelihood against dynamax and the weighted MHE against do-mpc,
  ``python -m jaxdip.bench.peers`` after ``pip install ".[peers]"`` (the only module that imports them).
"""
